"""``posecast serve``, ``posecast token`` and ``posecast demo`` (posecast.cli.serve)."""

from __future__ import annotations

import json
import logging
import re
import socket
import subprocess
import sys

import pytest

from posecast.cli import main
from tests.cli.conftest import user_error


def test_serve_without_a_secret_is_a_config_error(capsys, monkeypatch) -> None:
    """No POSECAST_TOKEN_SECRET and no --dev: refused before any socket is opened."""
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    err = user_error(capsys, main(["serve", "--port", "0"]), "CONFIG_INVALID")
    assert "POSECAST_TOKEN_SECRET" in err and "--dev" in err.splitlines()[-1]


@pytest.mark.parametrize(
    ("argv", "env", "said"),
    [
        (["--tick-hz", "nan"], {}, "--tick-hz nan must be in [1, 240]"),
        ([], {"POSECAST_TICK_HZ": "nan"}, "POSECAST_TICK_HZ=nan must be in [1, 240]"),
        (
            ["--redis-timeout-s", "2"],
            {},
            "--redis-node-ttl-s 3 must be above timeout + max(heartbeat / 2 + timeout,"
            " heartbeat) = 4.5 s, with --redis-timeout-s 2 and --redis-heartbeat-s 1",
        ),
        (["--redis", "redis://h:port/0"], {}, "--redis is not a well-formed URL (not shown"),
    ],
)
def test_serve_names_a_bad_setting_as_the_user_gave_it(
    capsys, monkeypatch, argv: list[str], env: dict[str, str], said: str
) -> None:
    """``posecast serve --tick-hz nan`` said ``tick_hz must be in [1, 240]``."""
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    err = user_error(capsys, main(["serve", "--dev", *argv]), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {said}" in err, err
    assert "tick_hz" not in err and "redis_" not in err, err


def test_serve_names_a_models_dir_from_the_environment(capsys, monkeypatch) -> None:
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("POSECAST_MODELS_DIR", "/no/such/models")
    err = user_error(capsys, main(["serve", "--dev"]), "MODEL_INVALID")
    assert "leave out POSECAST_MODELS_DIR" in err.splitlines()[-1], err


@pytest.mark.parametrize(
    ("argv", "env", "named"),
    [
        (["--models-dir", "/no/such/a"], {}, "--models-dir"),
        (["--models", "/no/such/a"], {"POSECAST_MODELS_DIR": "/no/such/b"}, "--models-dir"),
        ([], {"POSECAST_MODELS_DIR": "/no/such/b"}, "POSECAST_MODELS_DIR"),
    ],
)
def test_serve_names_the_models_dir_as_the_config_names_it(
    capsys, monkeypatch, argv: list[str], env: dict[str, str], named: str
) -> None:
    """cmd_serve worked out the models directory's name from os.environ itself,
    beside the config's own naming: it asks config.setting_names now."""
    import os

    import posecast.online.config as config

    def names(*a: object) -> dict[str, str]:  # marked, to tell its name from another
        out = setting_names(*a)  # type: ignore[arg-type]
        return out | {"models_dir": f"<{out['models_dir']}>"}

    setting_names = config.setting_names
    monkeypatch.setattr(config, "setting_names", names)
    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    err = user_error(capsys, main(["serve", "--dev", *argv]), "MODEL_INVALID")
    assert f"leave out <{named}> for the shipped models" in err.splitlines()[-1], err


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--port", "70000"], "CONFIG_INVALID"),
        (["--samples", "0"], "CONFIG_INVALID"),
        (["--samples", "100000000"], "CONFIG_INVALID"),  # was a MemoryError traceback
        (["--lookahead", "100000"], "CONFIG_INVALID"),  # was a MemoryError traceback
        (["--lookahead", "256"], "CONFIG_INVALID"),  # served, and every welcome refused
        (["--layouts", "hmd4"], "CONFIG_INVALID"),
        (["--backend", "cuda"], "CONFIG_INVALID"),
        (["--models-dir", "/no/such/models"], "MODEL_INVALID"),
    ],
)
def test_serve_user_error(capsys, monkeypatch, extra: list[str], code: str) -> None:
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    user_error(capsys, main(["serve", "--dev", *extra]), code)


def _serve_output(monkeypatch, capsys, argv: list[str], env: dict[str, str]) -> list[str]:
    """What ``posecast serve argv`` prints on stdout up to and once it listens (on 8765;
    the server itself is not run)."""
    import os

    import posecast.online.shell.app as app

    async def served(cfg, on_ready) -> None:
        on_ready(8765)

    monkeypatch.setattr(app, "serve_until_signal", served)
    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    for name in ("posecast", "websockets"):  # serve configures them: give them back after
        logger = logging.getLogger(name)
        monkeypatch.setattr(logger, "handlers", list(logger.handlers))
        monkeypatch.setattr(logger, "propagate", logger.propagate)
        monkeypatch.setattr(logger, "level", logger.level)
    assert main(["serve", *argv]) == 0
    return capsys.readouterr().out.splitlines()


def test_serve_dev_prints_export_lines_to_paste_and_the_viewer(capsys, monkeypatch) -> None:
    """``serve --dev`` gave its invented secret as prose only: the README told users to
    copy it into ``export POSECAST_TOKEN_SECRET=<SECRET>`` by hand, and nothing said
    where the viewer was."""
    out = _serve_output(monkeypatch, capsys, ["--dev", "--host", "0.0.0.0"], {})
    secret = re.fullmatch(r"posecast: --dev: token secret for this run: (\S+)", out[0])
    assert secret, out
    # Tests and SDK helpers read the first two lines so: the secret, then the port.
    assert out[1] == "posecast: listening on ws://0.0.0.0:8765"
    assert out[2:] == [
        "posecast: --dev: viewer at http://127.0.0.1:8765/viewer/ (this machine only)",
        "posecast: --dev: for a client in another shell, paste:",
        f"export POSECAST_TOKEN_SECRET={secret.group(1)}",
        "export POSECAST_URL=ws://127.0.0.1:8765/",
    ]
    pasted = subprocess.run(
        ["bash", "-c", f'{out[4]}; {out[5]}; echo "$POSECAST_TOKEN_SECRET $POSECAST_URL"'],
        capture_output=True, text=True, check=True, timeout=30,
    )  # fmt: skip
    assert pasted.stdout == f"{secret.group(1)} ws://127.0.0.1:8765/\n"


def test_serve_dev_with_a_secret_set_prints_the_viewer_and_never_the_secret(
    capsys, monkeypatch
) -> None:
    out = _serve_output(monkeypatch, capsys, ["--dev"], {"POSECAST_TOKEN_SECRET": "k" * 32})
    assert out == [
        "posecast: listening on ws://127.0.0.1:8765",
        "posecast: --dev: viewer at http://127.0.0.1:8765/viewer/ (this machine only)",
    ]
    assert _serve_output(monkeypatch, capsys, [], {"POSECAST_TOKEN_SECRET": "k" * 32}) == [
        "posecast: listening on ws://127.0.0.1:8765"
    ]


def test_serve_writes_an_ipv6_host_in_brackets(capsys, monkeypatch) -> None:
    # It printed ws://:::8765, which no URL parser reads.
    out = _serve_output(monkeypatch, capsys, ["--host", "::"], {"POSECAST_TOKEN_SECRET": "k" * 32})
    assert out == ["posecast: listening on ws://[::]:8765"]


def test_serve_names_both_families_for_every_interface(capsys, monkeypatch) -> None:
    # --host "" (every IPv4 and IPv6 interface) printed ws://:8765, which names neither.
    out = _serve_output(monkeypatch, capsys, ["--host", ""], {"POSECAST_TOKEN_SECRET": "k" * 32})
    assert out == ["posecast: listening on ws://0.0.0.0:8765 and ws://[::]:8765"]


@pytest.mark.parametrize("host", ["::", "::1", "0.0.0.0", "127.0.0.1", "localhost"])
def test_serve_dev_prints_urls_that_reach_the_bound_server(host: str) -> None:
    """``--host ::`` printed 127.0.0.1, but asyncio binds ``::`` IPv6-only: nothing
    answered there. Each printed URL is dialled on a server bound as posecast binds
    (asyncio's create_server, which websockets' serve calls)."""
    import asyncio

    from posecast.cli.serve import dev_lines

    if ":" in host and not socket.has_ipv6:
        pytest.skip("no IPv6 here")

    async def dial() -> list[str]:
        try:
            server = await asyncio.start_server(lambda r, w: w.close(), host, 0)
        except OSError as exc:  # pragma: no cover - a machine without that address
            pytest.skip(f"cannot bind {host}: {exc}")
        port = server.sockets[0].getsockname()[1]
        lines = dev_lines(host, port, "s" * 32)
        try:
            for url in (lines[0].split()[4], lines[3].split("=", 1)[1]):
                address = url.split("//", 1)[1].rsplit(":", 1)[0].strip("[]")
                _, writer = await asyncio.open_connection(address, port)
                writer.close()
        finally:
            server.close()
        return lines

    lines = asyncio.run(dial())
    assert lines[0].endswith("/viewer/ (this machine only)"), lines
    if host.startswith(":"):
        assert "http://[::1]:" in lines[0] and lines[3].startswith(
            "export POSECAST_URL=ws://[::1]:"
        )


def test_serve_dev_on_an_address_that_is_not_loopback_says_there_is_no_viewer() -> None:
    """The viewer line said "(this machine only)" for ``--host 192.168.x.y`` too, but
    /viewer/token hands tokens to loopback peers only (shell.http): the page got 403."""
    from posecast.cli.serve import dev_lines

    assert dev_lines("192.0.2.7", 8765, "s" * 32) == [
        "posecast: --dev: no viewer here: its dev tokens need a loopback bind, and host"
        " 192.0.2.7 is not one (--host 127.0.0.1, the default, or 0.0.0.0 is)",
        "posecast: --dev: for a client in another shell, paste:",
        f"export POSECAST_TOKEN_SECRET={'s' * 32}",
        "export POSECAST_URL=ws://192.0.2.7:8765/",
    ]
    assert dev_lines("2001:db8::7", 8765, None)[0].startswith("posecast: --dev: no viewer here")


def test_serve_logs_each_posecast_variable_that_sets_nothing(capsys, monkeypatch) -> None:
    """POSECAST_REDIS (for POSECAST_REDIS_URL) used to leave a node silently embedded."""
    import posecast.online.shell.app as app

    async def served(cfg, on_ready) -> None:  # the server itself is not under test
        assert cfg.redis_url == ""

    monkeypatch.setattr(app, "serve_until_signal", served)
    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "s" * 32)
    monkeypatch.setenv("POSECAST_REDIS", "redis://redis:6379/0")
    for name in ("posecast", "websockets"):  # serve configures them: give them back after
        logger = logging.getLogger(name)
        monkeypatch.setattr(logger, "handlers", list(logger.handlers))
        monkeypatch.setattr(logger, "propagate", logger.propagate)
        monkeypatch.setattr(logger, "level", logger.level)
    assert main(["serve", "--port", "0"]) == 0
    lines = [json.loads(ln) for ln in capsys.readouterr().err.splitlines() if ln.startswith("{")]
    (warning,) = [ln for ln in lines if ln["event"] == "unknown setting ignored"]
    assert warning["level"] == "WARNING" and warning["variable"] == "POSECAST_REDIS"
    assert warning["did_you_mean"] == "POSECAST_REDIS_URL"


def test_token_mints_a_token_the_server_verifies(capsys, monkeypatch) -> None:
    import time

    from posecast.online.auth.tokens import verify

    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "e" * 32)
    args = ["token", "--room", "R", "--player", "P", "--role", "backend", "--rooms", "A,B"]
    assert main([*args, "--ttl", "60"]) == 0
    claims = verify(b"e" * 32, capsys.readouterr().out.strip(), now=time.time())
    assert (claims.room, claims.player, claims.role, claims.rooms) == (
        "R",
        "P",
        "backend",
        ("A", "B"),
    )
    assert claims.exp - claims.iat == 60
    monkeypatch.delenv("POSECAST_TOKEN_SECRET")
    err = user_error(capsys, main(["token", "--room", "R", "--player", "P"]), "CONFIG_INVALID")
    assert "POSECAST_TOKEN_SECRET" in err


@pytest.mark.parametrize(
    "extra",
    [
        ["--ttl", "0"],
        ["--ttl", "-5"],
        ["--ttl", str(10**9)],
        ["--rooms", "A,B"],  # extra rooms are for backends
        ["--secret", "short"],
        ["--player", "a b"],  # not a wire id: every client's decoder would refuse it
        ["--player", "p" * 65],
        ["--room", "lob by"],
    ],
    ids=[
        "ttl-0",
        "ttl-negative",
        "ttl-too-long",
        "rooms-without-backend",
        "short-secret",
        "player-not-an-id",
        "player-too-long",
        "room-not-an-id",
    ],
)
def test_token_user_error(capsys, monkeypatch, extra: list[str]) -> None:
    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "e" * 32)
    rc = main(["token", "--room", "R", "--player", "P", *extra])
    user_error(capsys, rc, "CONFIG_INVALID")


def test_demo_runs_a_room(capsys) -> None:
    """make run: the server, two simulated headsets and a spectator on loopback."""
    assert main(["demo", "--port", "0", "--seconds", "5", "--samples", "8"]) == 0
    stdout = capsys.readouterr().out
    assert "posecast demo: server on ws://127.0.0.1:" in stdout
    rates = {
        m.group(1): float(m.group(2))
        for m in re.finditer(r"^(alice|bob):\s+([\d.]+) poses/s", stdout, flags=re.MULTILINE)
    }
    assert set(rates) == {"alice", "bob"}, stdout
    assert all(r > 20 for r in rates.values()), rates


def test_demo_stops_cleanly_on_sigterm() -> None:
    """`kill` or a process manager stops make run's demo as Ctrl-C does (it was killed
    by the signal, exit 143, the server never drained)."""
    import signal

    argv = [sys.executable, "-m", "posecast", "demo", "--port", "0", "--samples", "8"]
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as p:
        assert p.stdout is not None
        out = [p.stdout.readline() for _ in range(3)]  # server, viewer, the first rates
        assert out[1].startswith("viewer: "), out
        p.send_signal(signal.SIGTERM)
        rest, _ = p.communicate(timeout=30)
    assert p.returncode == 0, (out, rest)
    assert "Traceback" not in rest, rest


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--samples", "0"], "CONFIG_INVALID"),
        (["--samples", "100000000"], "CONFIG_INVALID"),  # was a MemoryError traceback
        (["--seconds", "-1"], "CONFIG_INVALID"),
        (["--port", "-1"], "CONFIG_INVALID"),
        (["--bvh", "/no/such/file.bvh"], "BVH_INVALID"),
    ],
)
def test_demo_user_error(capsys, extra: list[str], code: str) -> None:
    user_error(capsys, main(["demo", *extra]), code)


def test_demo_on_a_port_in_use_is_a_config_error(capsys) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rc = main(["demo", "--port", str(port), "--seconds", "1", "--samples", "8"])
    err = user_error(capsys, rc, "CONFIG_INVALID")
    assert f"127.0.0.1:{port}" in err


@pytest.mark.parametrize("workers", ["1", "2"])
def test_serve_on_a_port_in_use_is_a_config_error_with_any_workers(
    capsys, monkeypatch, workers: str
) -> None:
    """The supervisor of --workers 2 binds the port itself first: a port in use fails
    as the single process's does, before any worker starts."""
    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "k" * 32)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rc = main(["serve", "--port", str(port), "--workers", workers, "--samples", "8"])
    err = user_error(capsys, rc, "CONFIG_INVALID")
    assert f"127.0.0.1:{port}" in err
