"""``posecast.cli.main`` and the ``python -m posecast`` entry point: a user error is
``error [CODE]`` and a hint, exit 2, never a traceback; a bug keeps its traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from posecast.cli import main


def test_the_entry_point_prints_no_traceback() -> None:
    """``python -m posecast`` (what the ``posecast`` script runs): exit 2, code and hint."""
    out = subprocess.run(
        [sys.executable, "-m", "posecast", "token", "--room", "R", "--player", "P"],
        input="",
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin"},
    )
    assert out.returncode == 2, out.stderr
    assert out.stderr.startswith("posecast: error [CONFIG_INVALID]: "), out.stderr
    assert "\nhint: " in out.stderr and "Traceback" not in out.stderr


def test_a_bug_keeps_its_traceback(monkeypatch) -> None:
    """Only PosecastError is turned into a message; anything else is a bug to see."""
    from posecast.cli import serve

    def broken(args: object) -> int:
        raise RuntimeError("a bug")

    monkeypatch.setattr(serve, "cmd_token", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["token", "--room", "R", "--player", "P"])


def test_an_unknown_option_with_no_command_prints_no_traceback() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "posecast", "--bogus"],
        input="",
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin"},
    )
    assert out.returncode == 2, out.stderr
    assert "posecast: error [CONFIG_INVALID]: unknown option --bogus\n" in out.stderr
    assert "\nhint: see `posecast --help`" in out.stderr and "Traceback" not in out.stderr
