"""The live viewer in a real browser, against ``posecast demo`` (what ``make run`` starts).

Headless Chromium (Debian's ``chromium``, driven by ``playwright-core`` from
``client_sdk/typescript``) opens the ``viewer:`` URL the demo prints while its two
simulated headsets walk. ``client_sdk/typescript/scripts/viewer-check.mjs`` takes
real screenshots a few hundred milliseconds apart and measures them, first of the
procedural skinned meshes (``&avatar=mesh``), then of the stick figures
(``&avatar=sticks``), then of the humanoid models the page opens with (a generated VRM
and, ``&model=gltf``, a glTF humanoid of other proportions, bound by the TypeScript
SDK's three.js binding); this test asserts on the numbers. The models' bound
skeletons are read back in the page on every frame for 5 s: their hands and feet stay
within 2 cm of the streamed positions. The binding's cost for 16 avatars is printed,
and V8's sampling heap profiler sees no allocation in its update path over 600 frames
(and does see one when each avatar's pose copies its rotations). Every way, both
players are drawn (enough pixels in each player's colour), they move between two
screenshots (avatar pixels change), and the players' names are on the page. The
procedural meshes' limbs stay on their joints: on a frozen frame, next to no pixel of a
player's colour lies outside that player's body as the streamed joints place it (each
piece's half-width plus 4 cm around its bone, at its depth), and the page's CPU skinning
puts the mesh's rings at the joints and halfway along each bone within 3 cm of the
streamed joint positions; with four bones turned off their joints on purpose, both
checks fail. The ``s`` key switches to sticks and back. The screenshots stay in
``$TMPDIR/posecast-viewer/`` for a human to look at.

Setup, done here so that ``make test`` needs nothing else: ``npm ci`` in
``client_sdk/typescript`` when ``node_modules`` is missing or older than
``package-lock.json`` (the same stamp the Makefile's ``ts-deps`` uses), and
``apt-get install -y chromium`` when ``/usr/bin/chromium`` is missing and we are
root. Without Node, or without Chromium and root, the test is skipped with the
reason (``pytest -ra`` lists it).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest

from posecast.skeleton import reference_offsets

ROOT = Path(__file__).resolve().parents[2]
TS = ROOT / "client_sdk" / "typescript"
STAMP = TS / "node_modules" / ".installed"
DEBIAN_CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM = Path(os.environ.get("CHROMIUM", str(DEBIAN_CHROMIUM)))
SHOTS = Path(tempfile.gettempdir()) / "posecast-viewer"
# viewer-check.mjs picks a pair of shots with each player at least this visible
# (its VISIBLE_PIXELS): the walkers cross and may hide one another for a moment.
MIN_PLAYER_PIXELS = 1000  # each stick figure is ~4000-8000 pixels at 1000 x 640
MIN_MESH_PIXELS = 5000  # each skinned mesh ~10000-20000
ATTACHED_M = 0.03  # the mesh's rings from the streamed joints (0 with FK-consistent poses)
MAX_STRAY_SHARE = 0.01  # of a player's pixels, outside its body around the streamed bones
MODEL_ENDS_M = 0.02  # the models' hands and feet from the streamed hand and foot positions
BENCH_CELLS = 600 * 16  # frames x avatars in the heap check: one allocation each, >= these bytes

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def _skip(reason: str) -> None:
    pytest.skip(f"VIEWER TEST NOT RUN: {reason}")


@pytest.fixture(scope="session")
def node_modules() -> Path:
    """``client_sdk/typescript/node_modules``, installed with ``npm ci`` if stale."""
    npm = shutil.which("npm")
    if npm is None or shutil.which("node") is None:
        _skip("Node.js/npm is not installed (Node 20+ is needed for the TypeScript SDK)")
    assert npm is not None
    lock = TS / "package-lock.json"
    if not STAMP.exists() or STAMP.stat().st_mtime < lock.stat().st_mtime:
        subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=TS, check=True, timeout=600)
        STAMP.touch()
    return TS / "node_modules"


@pytest.fixture(scope="session")
def chromium() -> Path:
    """Debian's chromium, installed with apt-get when missing and we are root."""
    if not CHROMIUM.exists():
        apt = shutil.which("apt-get")
        if os.geteuid() != 0 or apt is None or CHROMIUM != DEBIAN_CHROMIUM:
            _skip(f"{CHROMIUM} is missing and cannot be installed here (needs root and apt-get)")
        assert apt is not None
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        for args in (["update"], ["install", "-y", "chromium"]):
            subprocess.run([apt, *args], check=True, timeout=900, env=env, capture_output=True)
    return CHROMIUM


def _viewer_url(log: Path, proc: subprocess.Popen[bytes], timeout_s: float = 60.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in log.read_text().splitlines():
            if line.startswith("viewer: "):
                return line.removeprefix("viewer: ").strip()
        if proc.poll() is not None:
            pytest.fail(f"posecast demo exited with {proc.returncode}:\n{log.read_text()}")
        time.sleep(0.1)
    pytest.fail(f"posecast demo printed no viewer URL:\n{log.read_text()}")


def _drawn_and_moving(view: dict[str, Any], min_pixels: int) -> dict[str, dict[str, Any]]:
    players = {p["name"]: p for p in view["players"]}
    assert set(players) == {"Alice", "Bob"}, view["players"]
    colours = {p["color"] for p in players.values()}
    assert len(colours) == 2, "each player has a colour of its own"
    for name, p in players.items():
        assert p["drawn"], name
        for shot in ("pixels_a", "pixels_b"):
            assert p[shot] >= min_pixels, f"{name} is not drawn as {view['mode']}: {p}"
    # They move: avatar pixels change between two screenshots 400 ms apart.
    assert view["changed_skeleton_pixels"] >= 400, view
    assert view["changed_pixels"] >= view["changed_skeleton_pixels"]
    return players


def test_viewer_draws_moving_avatars_with_names(
    node_modules: Path, chromium: Path, tmp_path: Path
) -> None:
    SHOTS.mkdir(exist_ok=True)
    log = tmp_path / "demo.out"
    with log.open("wb") as out:
        demo = subprocess.Popen(
            # Long enough for every pass of the check on a loaded 2-core machine (it takes
            # 80 to 190 s); the check's own deadline comes first.
            [sys.executable, "-m", "posecast", "demo", "--port=0", "--seconds=480", "--samples=8"],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        url = _viewer_url(log, demo)
        assert url.startswith("http://127.0.0.1:") and url.endswith("/viewer?room=demo")
        check = subprocess.run(
            ["node", "scripts/viewer-check.mjs", url, str(SHOTS), "400"],
            cwd=TS,
            env={**os.environ, "CHROMIUM": str(chromium)},
            capture_output=True,
            text=True,
            timeout=420,
        )
    finally:
        demo.terminate()
        demo.wait(timeout=30)
    lines = check.stdout.strip().splitlines()
    assert lines, f"viewer-check printed nothing:\n{check.stderr}"
    result = json.loads(lines[-1])
    print(json.dumps({k: v for k, v in result.items() if k != "logs"}, indent=1))
    assert "error" not in result, result
    assert check.returncode == 0, check.stderr

    # The procedural skinned meshes (avatar=mesh), drawn and moving.
    mesh = result["mesh"]
    assert mesh["mode"] == "mesh", mesh
    players = _drawn_and_moving(mesh, MIN_MESH_PIXELS)
    assert {p["shown"] for p in players.values()} == {"mesh"}, players

    # Limbs attached, on the screen: a frozen frame's pixels lie near the player's bones.
    # (On a frame with both bodies inside the view, which the check waits for.)
    assert mesh["in_view"], mesh
    strays = {s["player"]: s for s in mesh["strays"]}
    assert set(strays) == {"alice", "bob"}, strays
    for s in strays.values():
        assert s["bones"] == 23 and s["pixels"] >= MIN_MESH_PIXELS, s
        assert s["stray_pixels"] <= MAX_STRAY_SHARE * s["pixels"], s
    # ... and in the page's skinning of the mesh, against the streamed joint positions.
    skin = mesh["skin"]
    assert set(skin) == {"alice", "bob"}, skin
    for s in skin.values():
        assert s["samples"] == 20, s
        assert s["max_m"] <= ATTACHED_M and s["bone_max_m"] <= 0.001, s
        assert 0.8 <= s["scale"] <= 1.25, s  # the demo's players are of ordinary height

    # Both checks notice limbs off their joints: the page turns both thighs out sideways and
    # both upper arms forward (90 degrees each, in their own frames), then measures again.
    # Counted over both players: one of them may hide behind the other.
    bent = mesh["tampered"]
    assert bent["in_view"], bent
    bent_pixels = sum(s["pixels"] for s in bent["strays"])
    bent_strays = sum(s["stray_pixels"] for s in bent["strays"])
    assert bent_strays >= 3 * MAX_STRAY_SHARE * bent_pixels, bent
    for s in bent["skin"]:
        assert s["max_m"] >= 0.1, s

    # The mesh is built on the server's reference body.
    assert result["rest_offsets"] == reference_offsets().tolist()

    # The `s` key toggles to the stick figures and back.
    t = mesh["toggle"]
    assert (t["key_once"], t["key_twice"]) == ("sticks", "mesh"), t
    assert set(t["shown_once"]) == {"sticks"} and set(t["shown_twice"]) == {"mesh"}, t

    # ?avatar=sticks: the stick figures, drawn and moving.
    sticks = result["sticks"]
    assert sticks["mode"] == "sticks", sticks
    players = _drawn_and_moving(sticks, MIN_PLAYER_PIXELS)
    assert {p["shown"] for p in players.values()} == {"sticks"}, players

    # Names: in the player list, and over the heads.
    assert {"Alice", "Bob"} <= set(result["list_names"]), result
    assert {"Alice", "Bob"} <= set(result["label_names"]), result
    assert result["status"].startswith("room demo · 2 players"), result["status"]
    assert "· posecast.v2" in result["status"], result["status"]  # the SDK's default
    # The models (the page opens on them): a VRM, and a glTF humanoid of other proportions.
    models = result["models"]
    for kind in ("vrm", "gltf"):
        m = models[kind]
        assert (m["mode"], m["model"]) == ("model", kind), m
        players = _drawn_and_moving(m, MIN_MESH_PIXELS)
        assert {p["shown"] for p in players.values()} == {"model"}, players
        track = {t["player"]: t for t in m["track"]}
        assert set(track) == {"alice", "bob"}, m["track"]
        for t in track.values():
            assert t["frames"] >= 15, t  # 5 s of frames, at 3 fps or more on software GL
            assert t["hands_max_m"] <= MODEL_ENDS_M and t["feet_max_m"] <= MODEL_ENDS_M, (kind, t)
            # They move: the demo's walkers pause 2.4 s of each 12 s clip, and cover 0.4 to
            # 3.5 m in 5 s (some 15 m when the clip loops back); still, 0.01 m.
            assert t["hips_path_m"] >= 0.2 and t["hand_path_m"] >= 0.2, (kind, t)

    # The binding for 16 avatars: its cost (printed), and no allocation in its update path.
    bench = result["benchmark"]
    run, allocating = bench["run"], bench["allocating"]
    assert (run["avatars"], run["frames"]) == (16, 600), run
    print(
        f"three.js binding, 16 avatars: {run['update_ms_per_frame']:.3f} ms/frame "
        f"(+ {run['matrices_ms_per_frame']:.3f} ms/frame three.js matrix update); "
        f"update path allocated {run['update_allocated_bytes']} B over 600 frames "
        f"(copying each pose: {allocating['update_allocated_bytes']} B)"
    )
    assert run["update_allocated_bytes"] < BENCH_CELLS, run
    assert allocating["found_update_frame"], allocating
    assert allocating["update_allocated_bytes"] >= 10 * BENCH_CELLS, allocating

    assert len(result["screenshots"]) == 10
    for path in result["screenshots"]:
        assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    errors = [line for line in result["logs"] if line.startswith(("error", "pageerror"))]
    assert not errors, errors
