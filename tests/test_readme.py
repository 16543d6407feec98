"""The README's quick-start example runs as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text("utf-8"), flags=re.DOTALL)


def test_readme_has_a_short_example() -> None:
    blocks = _python_blocks()
    assert blocks, "README lost its Python example"
    assert len(blocks[0].strip().splitlines()) <= 16  # 15 lines of code and a blank


def test_readme_example_runs(capsys: pytest.CaptureFixture[str]) -> None:
    exec(compile(_python_blocks()[0], str(README), "exec"), {"__name__": "__readme__"})
    out = capsys.readouterr().out
    assert re.search(r"frame \d+: sample \d+, head at \[", out)
    assert re.search(r"\d+ poses, \d+ sample transitions", out)


def _first_block(path: Path, lang: str) -> str:
    blocks = re.findall(rf"```{lang}\n(.*?)```", path.read_text("utf-8"), flags=re.DOTALL)
    assert blocks, f"{path} lost its {lang} example"
    return str(blocks[0])


def test_sdk_snippets_match_the_sdk_readmes() -> None:
    """The SDK quick starts in this README are the ones the SDKs' own tests run."""
    root = README.parent
    text = README.read_text("utf-8")
    python = _first_block(root / "client_sdk" / "python" / "README.md", "python")
    typescript = _first_block(root / "client_sdk" / "typescript" / "README.md", "ts")
    assert f"```python\n{python}```" in text
    assert f"```ts\n{typescript}```" in text
    for code in (python, typescript):
        assert len([line for line in code.splitlines() if line.strip()]) <= 15
