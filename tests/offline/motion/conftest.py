"""Fixtures of the motion readers' tests: the golden Acclaim pair written to a temporary folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from .acclaim_fixtures import GOLDEN_AMC, GOLDEN_ASF, write_text


@pytest.fixture
def golden(tmp_path: Path) -> tuple[Path, Path]:
    return (
        write_text(tmp_path / "golden.asf", GOLDEN_ASF),
        write_text(tmp_path / "golden_01.amc", GOLDEN_AMC),
    )
