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


SDKS = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("readme", "source", "names"),
    [
        ("python/README.md", "python/src/posecast_client/errors.py",
         ["ConnectFailedError", "ConnectionLostError", "ConfigInvalidError", "TokenProviderError",
          "PosecastClientError", "not** an `OSError`"]),
        ("typescript/README.md", "typescript/src/errors.ts",
         ["ConfigInvalidError", "ConnectFailedError", "ConnectionClosedError", "TokenProviderError",
          "PosecastError", "`http://` or `https://`"]),
        ("csharp/README.md", "csharp/Runtime/Core/Errors.cs",
         ["ConfigInvalidException", "ConnectFailedException", "ConnectionLostException",
          "TokenProviderException", "PosecastException", "not** an `ArgumentException`"]),
    ],
)  # fmt: skip
def test_each_sdk_readme_says_what_to_catch_now(readme: str, source: str, names: list[str]) -> None:
    """Callers of the earlier SDKs caught the transport's exceptions (OSError,
    ArgumentException, a rewritten http:// URL): each README's 'Errors (changed)' note
    says what to catch instead, naming classes the SDK has."""
    text = (SDKS / readme).read_text("utf-8")
    at = text.index("Errors (changed)")
    note = text[at : text.find("\n#", at + 20) if "\n#" in text[at + 20 :] else None]
    code = (SDKS / source).read_text("utf-8")
    for name in names:
        assert name in note, (readme, name)
        if "`" not in name and " " not in name:
            assert re.search(rf"class {name}\b", code), (source, name)
