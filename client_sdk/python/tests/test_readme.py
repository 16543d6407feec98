"""The README's quick start runs as written, against a real server."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from sdk_helpers import DevServer

README = Path(__file__).resolve().parents[1] / "README.md"


def quick_start() -> str:
    blocks: list[str] = re.findall(r"```python\n(.*?)```", README.read_text("utf-8"), re.DOTALL)
    return blocks[0]


def test_quick_start_is_short() -> None:
    code = [ln for ln in quick_start().splitlines() if ln.strip()]
    assert len(code) <= 15


def test_quick_start_runs(
    dev_server: DevServer, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("POSECAST_URL", dev_server.url)
    monkeypatch.setenv("POSECAST_TOKEN_SECRET", dev_server.secret)
    exec(compile(quick_start(), str(README), "exec"), {"__name__": "__readme__"})
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "joined as ada"
    poses = [ln for ln in out[1:] if re.fullmatch(r"ada \d+ \[.*\]", ln)]
    assert len(poses) > 100  # 3 s at 60 Hz, less the look-ahead
