"""``posecast-sim`` and ``posecast-record`` end to end against a real server."""

from __future__ import annotations

import asyncio
import io
import json
import os
import subprocess
import sys
import time
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from peer_helpers import peer, url_of
from posecast_client.bvh import read_bvh
from posecast_client.cli import record, sim
from posecast_client.cli.common import connect_patiently, describe
from posecast_client.errors import ConfigInvalidError, ConnectFailedError
from posecast_client.protocol import Pose, Presence, Welcome
from posecast_client.recording import RecordingWriter, read_recording
from posecast_client.skeleton import JOINT_NAMES
from posecast_client.tokens import mint_token
from sdk_helpers import DevServer

DATA = Path(__file__).resolve().parent / "data"


def test_console_scripts_are_installed() -> None:
    scripts = {e.name: e.value for e in entry_points(group="console_scripts")}
    assert scripts["posecast-sim"] == "posecast_client.cli.sim:main"
    assert scripts["posecast-record"] == "posecast_client.cli.record:main"


def test_sim_and_record_end_to_end(dev_server: DevServer, tmp_path: Path, uid: str) -> None:
    env = dict(os.environ, POSECAST_URL=dev_server.url, POSECAST_TOKEN_SECRET=dev_server.secret)
    room = f"e2e-{uid}-0"
    rec_file, bvh_dir, report = tmp_path / "room.pcrec", tmp_path / "bvh", tmp_path / "sim.json"
    recorder = subprocess.Popen(
        [sys.executable, "-m", "posecast_client.cli.record", "--room", room,
         "--out", str(rec_file), "--seconds", "4.5", "--bvh", str(bvh_dir)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        time.sleep(1.0)  # let the recorder join first
        done = subprocess.run(
            [sys.executable, "-m", "posecast_client.cli.sim", "--players", "2",
             "--room-prefix", f"e2e-{uid}", "--duration", "2.5", "--json", str(report)],
            env=env, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        out, err = recorder.communicate(timeout=30)
    finally:
        recorder.kill()
        recorder.wait()
    assert done.returncode == 0, done.stdout + done.stderr
    assert "poses received" in done.stdout and "latency" in done.stdout
    summary = json.loads(report.read_text())
    assert summary["failed"] == {} and summary["players"] == 2
    assert 200 <= summary["frames_sent"] <= 310  # 2 x 2.5 s x 60 Hz
    for seen in summary["poses_from"].values():  # each player sees both avatars
        assert len(seen) == 2 and min(seen.values()) > 60, summary["poses_from"]
    assert summary["poses_per_s"] > 100, summary
    # Poses are shown at their own frame by default (no look-ahead): what is left is the
    # frame queue, the tick and the loopback, more than nothing and far from seconds.
    assert 0.0 < summary["latency_ms_p50"] <= summary["latency_ms_p99"] < 2000.0
    assert abs(summary["clock_offset_ms"]) < 5.0

    assert recorder.returncode == 0, err
    rec = read_recording(rec_file)
    assert rec.header["room"] == room and rec.rate_hz == 60.0
    kinds = {type(m) for _, m in rec.messages}
    assert {Welcome, Pose, Presence} <= kinds
    poses = rec.poses()
    assert len(poses) == 2
    for player, mine in poses.items():
        bvh = read_bvh(bvh_dir / f"{player}.bvh")
        assert bvh.names == JOINT_NAMES and bvh.frame_time_s == pytest.approx(1 / 60)
        _, fk_pos = bvh.fk()
        t0 = min(p.t for p in mine)
        frame = [round((p.t - t0) * 60) for p in mine]
        # Every 60 Hz tick a pose stands for has a frame (two poses whose times round
        # to one tick, a late tick and the next, share it: the later one shows).
        assert bvh.n_frames >= len(set(frame)) > 60
        err = np.linalg.norm(fk_pos[frame] - np.stack([p.positions for p in mine]), axis=-1)
        assert np.median(err) < 0.005  # the exported skeleton reproduces the poses
        assert f"{player}: {bvh_dir / (player + '.bvh')}" in out


def test_sim_replays_bvh_with_noise_and_dropout(
    dev_server: DevServer, capsys: pytest.CaptureFixture[str], uid: str
) -> None:
    clip = str(DATA / "walk_cmu_mb.bvh")
    code = sim.main(
        ["--url", dev_server.url, "--secret", dev_server.secret, "--room-prefix", f"bvh-{uid}",
         "--players", "2", "--rooms", "2", "--duration", "1.5", "--bvh", clip,
         "--noise-m", "0.002", "--noise-deg", "1", "--dropout", "0.05", "-q"]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert "2 players in 2 rooms" in out and "failed players 0" in out


def test_sim_reports_refused_players(
    dev_server: DevServer, capsys: pytest.CaptureFixture[str]
) -> None:
    code = sim.main(["--url", dev_server.url, "--secret", "w" * 32, "--players", "1",
                     "--duration", "1"])  # fmt: skip
    assert code == 1
    out, err = capsys.readouterr()
    assert "UnauthenticatedError" in out
    assert "posecast-sim: error [UNAUTHENTICATED]: 1 of 1 player sessions failed" in err, err
    assert "hint: the token does not verify" in err and "Traceback" not in err


def _failure(capsys: pytest.CaptureFixture[str], main: object, argv: list[str], code: str) -> str:
    """Run a tool's ``main`` into a failure met while running: exit 1, no traceback, an
    ``error [CODE]`` line with a hint under it; returns stderr."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)  # type: ignore[operator]
    err = capsys.readouterr().err
    assert exit_.value.code == 1, err
    assert "Traceback" not in err, err
    lines = err.splitlines()
    at = [i for i, ln in enumerate(lines) if f": error [{code}]: " in ln]
    assert at, err
    assert lines[at[0] + 1].startswith("hint: ") and len(lines[at[0] + 1]) > 10, err
    return err


def test_record_failures_print_a_code_and_a_hint(
    dev_server: DevServer, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """What a recorder meets while running: the server refusing its token or its room,
    no server at the URL, a file to export that is missing or not a recording."""
    out = ["--out", str(tmp_path / "r.pcrec"), "--seconds", "1"]
    server = ["--url", dev_server.url, *out]
    err = _failure(capsys, record.main, [*server, "--secret", "w" * 32, "--room", "r"],
                   "UNAUTHENTICATED")  # fmt: skip
    assert "token signature does not verify" in err
    token = mint_token(dev_server.secret, room="r", player="rec")
    err = _failure(capsys, record.main, [*server, "--token", token, "--room", "other"],
                   "FORBIDDEN")  # fmt: skip
    assert "room" in err
    err = _failure(capsys, record.main, ["--url", "ws://127.0.0.1:9/", "--secret", "s" * 32,
                                         "--room", "r", *out], "UNREACHABLE")  # fmt: skip
    assert "ws://127.0.0.1:9/" in err and "posecast serve --dev" in err
    export = ["--bvh", str(tmp_path / "bvh"), "--export"]
    err = _failure(capsys, record.main, [*export, str(tmp_path / "none.pcrec")], "FILE_INVALID")
    assert "none.pcrec" in err
    bogus = tmp_path / "notes.txt"
    bogus.write_text("not msgpack at all\n", encoding="utf-8")
    err = _failure(capsys, record.main, [*export, str(bogus)], "FILE_INVALID")
    assert "recording" in err


def test_sim_failures_print_a_code_and_a_hint(capsys: pytest.CaptureFixture[str]) -> None:
    code = sim.main(["--url", "ws://127.0.0.1:9/", "--secret", "s" * 32, "--duration", "0.5",
                     "-q"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert "posecast-sim: error [UNREACHABLE]: 2 of 2 player sessions failed" in err, err
    assert "hint: is a server running there?" in err


def test_record_exports_an_existing_recording(
    dev_server: DevServer, tmp_path: Path, uid: str
) -> None:
    """``--export`` alone (no server): a recording made here, then exported."""
    room = f"exp-{uid}-0"  # the sim's first room with prefix exp-UID
    rec_file = tmp_path / "r.pcrec"
    env = dict(os.environ, POSECAST_URL=dev_server.url, POSECAST_TOKEN_SECRET=dev_server.secret)
    recorder = subprocess.Popen(
        [sys.executable, "-m", "posecast_client.cli.record", "--room", room, "--out",
         str(rec_file), "--seconds", "2.5"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    time.sleep(0.8)
    assert sim.main(["--url", dev_server.url, "--secret", dev_server.secret, "--players", "1",
                     "--room-prefix", f"exp-{uid}", "--duration", "1", "-q"]) == 0  # fmt: skip
    assert recorder.wait(30) == 0
    assert record.main(["--export", str(rec_file), "--bvh", str(tmp_path / "out")]) == 0
    assert len(list((tmp_path / "out").glob("*.bvh"))) == 1


def test_record_exports_a_recording_piped_to_it(tmp_path: Path) -> None:
    """'posecast-record --export /dev/stdin' (or a process substitution) read a pipe
    that cannot be read twice: it failed with FILE_INVALID ('not seekable'). It exports
    what the file gives."""
    rec_file = tmp_path / "r.pcrec"
    w = RecordingWriter(rec_file, url="ws://x/", room="r")
    for k in range(300):  # more than a pipe's buffer
        w.write(Pose("p-1", k, k / 60.0, np.zeros((19, 3)) + np.arange(19)[:, None] * 0.1))
    w.close()
    assert record.main(["--export", str(rec_file), "--bvh", str(tmp_path / "want")]) == 0
    done = subprocess.run(
        [sys.executable, "-m", "posecast_client.cli.record", "--export", "/dev/stdin",
         "--bvh", str(tmp_path / "out")],
        input=rec_file.read_bytes(), capture_output=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["p-1.bvh"]
    want = (tmp_path / "want" / "p-1.bvh").read_bytes()
    assert (tmp_path / "out" / "p-1.bvh").read_bytes() == want


def test_sim_churns_players_and_prints_progress(
    dev_server: DevServer, capsys: pytest.CaptureFixture[str], tmp_path: Path, uid: str
) -> None:
    """``--churn-every``: players leave on schedule and new ones take their places;
    ``--progress-every``: JSON progress lines while it runs."""
    report = tmp_path / "churn.json"
    code = sim.main(
        ["--url", dev_server.url, "--secret", dev_server.secret, "--room-prefix", f"ch-{uid}",
         "--players", "3", "--rooms", "1", "--duration", "3", "--churn-every", "0.5",
         "--progress-every", "0.5", "--json", str(report), "-q"]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    s = json.loads(report.read_text())
    assert s["players"] == 3 and s["failed"] == {} and s["connection_losses"] == 0, s
    assert 4 <= s["churned"] <= 6  # one leave every 0.5 s for 3 s
    # each leave made room for a new player, unless it came too close to the end
    assert 3 + s["churned"] - 1 <= s["sessions"] <= 3 + s["churned"]
    assert len(s["poses_from"]) == s["sessions"]
    assert 0 < s["first_pose_ms_p50"] <= s["first_pose_ms_max"] < 2000  # a new player's wait
    assert f"sessions {s['sessions']:8d}" in " ".join(out.split("  "))
    lines = [json.loads(x.split(" ", 2)[2]) for x in out.splitlines() if " progress " in x]
    assert len(lines) >= 4
    assert [x["poses"] for x in lines] == sorted(x["poses"] for x in lines)
    assert lines[-1]["poses"] > 0 and lines[-1]["connection_losses"] == 0
    assert all(x["active"] <= 3 for x in lines) and lines[-1]["active"] >= 2


def _mistake(capsys: pytest.CaptureFixture[str], main: object, argv: list[str]) -> str:
    """Run a tool's ``main`` on a command-line mistake: exit 2, no traceback, the
    server CLI's ``error [CONFIG_INVALID]`` line and a hint under it; returns stderr."""
    with pytest.raises(SystemExit) as exit_:
        main(argv)  # type: ignore[operator]
    err = capsys.readouterr().err
    assert exit_.value.code == 2, err
    assert "Traceback" not in err, err
    lines = err.splitlines()
    at = [i for i, ln in enumerate(lines) if ": error [CONFIG_INVALID]: " in ln]
    assert at, err
    assert lines[at[0] + 1].startswith("hint: ") and len(lines[at[0] + 1]) > 10, err
    return err


def test_sim_refuses_a_bvh_it_cannot_read(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Before connecting: a missing file, one that is not BVH, or a BVH of no rig the
    replay knows (its joints), with the server CLI's code for a BVH that cannot be read."""
    text = tmp_path / "notes.txt"
    text.write_text("hello\n", encoding="utf-8")
    norig = tmp_path / "norig.bvh"
    norig.write_text(
        "HIERARCHY\nROOT Foo\n{\n OFFSET 0 0 0\n"
        " CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
        " End Site\n {\n  OFFSET 0 1 0\n }\n}\n"
        "MOTION\nFrames: 1\nFrame Time: 0.0333333\n0 0 0 0 0 0\n",
        encoding="utf-8",
    )
    for path in (tmp_path / "none.bvh", text, norig):
        with pytest.raises(SystemExit) as exit_:
            sim.main(["--secret", "s" * 32, "--bvh", str(path)])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and "Traceback" not in err, err
        assert f"posecast-sim: error [BVH_INVALID]: {path}" in err and "\nhint: " in err, err


def test_sim_rejects_bad_churn_options(capsys: pytest.CaptureFixture[str]) -> None:
    err = _mistake(capsys, sim.main, ["--secret", "s" * 32, "--churn-every", "-1"])
    assert "posecast-sim: error [CONFIG_INVALID]: " in err and "must not be negative" in err
    err = _mistake(capsys, sim.main, ["--token", "t", "--players", "1", "--churn-every", "1"])
    assert "fresh token per player" in err


@pytest.mark.parametrize(
    ("tool", "argv", "says"),
    [
        ("sim", ["--bogus"], "unrecognized arguments: --bogus"),
        ("sim", ["--players", "many"], "invalid int value: 'many'"),
        ("sim", ["--secret", "s" * 32, "--players", "0"], "must be positive"),
        ("sim", ["--secret", "s" * 32, "--layout", "hmd9"], "--layout 'hmd9'"),
        ("sim", ["--token", "t", "--players", "2"], "one --token is one player"),
        ("sim", [], "neither a token nor a secret"),
        ("sim", ["--secret", "s" * 32, "--rate", "0"], "--rate 0.0 is not in [1, 1000]"),
        ("sim", ["--secret", "s" * 32, "--dropout", "2"], "--dropout 2.0 is not a share"),
        ("sim", ["--secret", "s" * 32, "--noise-m", "-1"], "must be finite and not negative"),
        ("sim", ["--secret", "s" * 32, "--noise-deg", "nan"], "must be finite and not negative"),
        ("sim", ["--secret", "s" * 32, "--json", "/nonexistent/d/x.json"], "no directory"),
        ("sim", ["--secret", "short"], "the secret has 5 characters"),
        ("sim", ["--secret", "s" * 32, "--ttl", "0"], "--ttl 0 is not in"),
        ("record", ["--bogus"], "unrecognized arguments: --bogus"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--seconds", "-1"], "positive number"),
        (
            "record",
            ["--secret", "s" * 32, "--room", "r", "--out", "/nonexistent/d/x.pcrec"],
            "no directory",
        ),
        ("record", ["--secret", "s" * 32], "--room is required"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--out", str(DATA)], "is a directory"),
        (
            "record",
            ["--secret", "s" * 32, "--room", "r", "--bvh", str(DATA / "walk_cmu_mb.bvh" / "o")],
            "is a file, not a directory",
        ),
        (
            "record",
            ["--export", str(DATA / "walk_cmu_mb.bvh"), "--bvh", str(DATA / "walk_cmu_mb.bvh")],
            "is a file, not a directory",
        ),
        ("record", ["--room", "r"], "neither a token nor a secret"),
        ("sim", ["--secret", "s" * 32, "--url", "notaurl"], "is not a WebSocket URL"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--url", "http://x/"], "WebSocket"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--url", "ws://"], "names no host"),
        ("sim", ["--secret", "s" * 32, "--url", "ws://"], "names no host"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--url", "ws://:8765/"], "no host"),
        ("sim", ["--secret", "s" * 32, "--url", "ws://:8765/"], "names no host"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--url", "ws://h:99999/"], "bad port"),
        ("sim", ["--secret", "s" * 32, "--url", "ws://h:99999/"], "has a bad port"),
        ("record", ["--secret", "s" * 32, "--room", "r", "--url", "ws://h/#x"], "#fragment"),
        ("sim", ["--secret", "s" * 32, "--url", "ws://h/#x"], "has a #fragment"),
        ("sim", ["--secret", "s" * 32, "--room-prefix", "lob by"], "not an id"),
        ("record", ["--secret", "s" * 32, "--room", "lob by"], "not an id"),
    ],
)
def test_a_command_line_mistake_prints_a_code_and_a_hint(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tool: str,
    argv: list[str],
    says: str,
) -> None:
    for name in ("POSECAST_TOKEN_SECRET", "POSECAST_TOKEN", "POSECAST_URL"):
        monkeypatch.delenv(name, raising=False)
    main = {"sim": sim.main, "record": record.main}[tool]
    err = _mistake(capsys, main, argv)
    assert f"posecast-{tool}: error [CONFIG_INVALID]: " in err and says in err, err


def test_a_bad_url_from_the_environment_is_named_so(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("POSECAST_URL", "ws://h:99999/")
    err = _mistake(capsys, record.main, ["--secret", "s" * 32, "--room", "r"])
    assert "error [CONFIG_INVALID]: POSECAST_URL: 'ws://h:99999/' has a bad port" in err, err
    assert "hint: a port is a number from 1 to 65535" in err, err


def test_describe_knows_the_clients_config_error() -> None:
    """A URL or token the client refuses at run time is CONFIG_INVALID with its hint,
    not a bug re-raised (posecast-sim reported it as INTERNAL, posecast-record as a
    traceback)."""
    exc = ConfigInvalidError("no token (got None)", hint="an unset environment variable?")
    assert describe(exc, "ws://h/") == (
        "CONFIG_INVALID",
        "no token (got None)",
        "an unset environment variable?",
    )


def test_recording_a_room_nobody_is_in_says_so_and_names_the_rooms_with_players(
    dev_server: DevServer, capsys: pytest.CaptureFixture[str], tmp_path: Path, uid: str
) -> None:
    """The README paired ``posecast-sim --rooms 2`` (rooms sim-0, sim-1) with
    ``posecast-record --room lobby``: the recording caught nothing, said '1 messages'
    and exited 0 without a word. It now warns, naming the room, and the hint names the
    rooms that have players (a --dev server tells a loopback client); exit 0 still."""
    env = dict(os.environ, POSECAST_URL=dev_server.url, POSECAST_TOKEN_SECRET=dev_server.secret)
    players = subprocess.Popen(
        [sys.executable, "-m", "posecast_client.cli.sim", "--players", "3", "--rooms", "2",
         "--room-prefix", f"play-{uid}", "--duration", "30", "-q"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        for _ in range(100):  # until both rooms have their players (or 20 s)
            rooms = dict(record.server_rooms(dev_server.url) or [])
            if rooms.get(f"play-{uid}-0") == 2 and rooms.get(f"play-{uid}-1") == 1:
                break
            time.sleep(0.2)
        bvh = tmp_path / "bvh"
        code = record.main(["--url", dev_server.url, "--secret", dev_server.secret,
                            "--room", f"lobby-{uid}", "--out", str(tmp_path / "l.pcrec"),
                            "--seconds", "0.5", "--bvh", str(bvh)])  # fmt: skip
    finally:
        players.terminate()
        players.wait(30)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "posecast-record: 1 message in " in err, err
    assert f"posecast-record: warning: no player's pose was seen in room lobby-{uid}" in err
    assert f"no BVH written to {bvh}" in err and not list(bvh.glob("*.bvh"))
    hint = next(ln for ln in err.splitlines() if ln.startswith("hint: "))
    assert f"play-{uid}-0 (2 players)" in hint and f"play-{uid}-1 (1 player)" in hint, hint
    assert f"lobby-{uid}" not in hint


def test_no_poses_hint_without_the_servers_rooms(capsys: pytest.CaptureFixture[str]) -> None:
    """A server that does not list its rooms (not --dev, another host, none there):
    the hint says to check the room name; players that joined but sent no pose are named."""
    assert record.server_rooms("ws://127.0.0.1:9/") is None
    hint = record.no_poses_hint("lobby", None)
    assert "check the room name (--room lobby)" in hint and "sim-0, sim-1" in hint
    assert "no room on this server has a player" in record.no_poses_hint("lobby", [("lobby", 0)])
    many = [(f"r{k}", 1) for k in range(10)]
    assert "r7 (1 player) and 2 more" in record.no_poses_hint("lobby", many)
    seen = record.Seen(messages=3, players={"p-2", "p-1"}, seconds=2.0)
    record.warn_no_poses("lobby", seen, "ws://127.0.0.1:9/", None)
    err = capsys.readouterr().err
    assert "warning: no player's pose was seen in room lobby in 2.0 s" in err
    assert "(players were in it: p-1, p-2; none streamed)" in err and "\nhint: " in err


@pytest.mark.parametrize(
    ("url", "asked"),
    [
        ("ws://127.0.0.1:8765/", True),
        ("ws://127.8.9.10:8765/", True),
        ("ws://[::1]:8765/", True),
        ("ws://localhost:8765/", True),
        ("WS://LOCALHOST:8765/", True),
        ("wss://localhost./", True),
        ("wss://posecast.example.com/", False),  # a production server: never asked
        ("ws://10.0.0.5:8765/", False),
        ("ws://[2001:db8::1]:8765/", False),
        ("ws://localhost.example.com/", False),
        ("ws://127.0.0.1.nip.io/", False),  # a name, however it looks: no DNS lookup
    ],
)
def test_the_rooms_are_asked_of_a_server_on_this_machine_only(
    monkeypatch: pytest.MonkeyPatch, url: str, asked: bool
) -> None:
    """The empty-room hint asked /viewer/rooms of any host, production servers too,
    and a host name's DNS lookup is not covered by the 2 s timeout."""
    opened: list[str] = []

    class Opener:
        def open(self, http: str, timeout: float) -> Any:
            opened.append(http)
            return io.BytesIO(b'[{"room": "sim-0", "players": 2}]')

    monkeypatch.setattr(record.urllib.request, "build_opener", lambda *a: Opener())
    rooms = record.server_rooms(url)
    assert (opened != []) == asked and record.is_loopback_host(url) == asked
    assert rooms == ([("sim-0", 2)] if asked else None)
    if asked:
        assert opened[0].endswith("/viewer/rooms") and opened[0].startswith("http")


def test_exporting_a_recording_without_poses_warns(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    rec = tmp_path / "empty.pcrec"
    w = RecordingWriter(rec, url="ws://x/", room="lobby")
    w.write(Presence("join", "lobby", "p-1", "P"))
    w.close()
    assert record.main(["--export", str(rec), "--bvh", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert f"warning: {rec} (room lobby) holds no player's pose; no BVH written" in err, err
    assert not list((tmp_path / "out").glob("*.bvh"))


@pytest.mark.parametrize("main", [sim.main, record.main])
def test_a_secret_that_starts_with_a_dash_is_never_echoed_and_gets_the_equals_hint(
    capsys: pytest.CaptureFixture[str], main: Any
) -> None:
    # argparse takes "-Secret..." for an option: the tools must not print it, and must
    # say how to pass such a value (the server CLI says the same).
    value = "-SuperSecretValue123456"
    with pytest.raises(SystemExit) as exit_:
        main(["--url", "ws://127.0.0.1:9/", "--secret", value])
    err = capsys.readouterr().err
    assert exit_.value.code == 2, err
    assert value not in err and "Traceback" not in err, err
    assert "(--secret=VALUE)" in err, err


def test_connect_patiently_retries_429_and_503_only() -> None:
    refusals = [503, 429]

    async def main() -> None:
        async with peer(refuse=lambda: refusals.pop(0) if refusals else None) as server:
            client = await connect_patiently(url_of(server), "token")
            await client.close()
        assert refusals == []  # both refusals were met and retried
        refusals.append(404)
        async with peer(refuse=lambda: refusals.pop(0) if refusals else None) as server:
            with pytest.raises(ConnectFailedError) as info:
                await connect_patiently(url_of(server), "token")
        assert info.value.status == 404 and refusals == []  # not retried

    asyncio.run(asyncio.wait_for(main(), 30.0))
