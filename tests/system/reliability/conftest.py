"""The reliability suite (docs/reliability.md): load, faults and hostile input against
real processes on loopback. Every test here carries the ``reliability`` marker, so
``pytest -m reliability`` runs just this suite (the CI subset; the long runs are
commands in docs/reliability.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # A conftest's hook sees every collected item, not only this folder's.
    for item in items:
        if Path(item.path).resolve().is_relative_to(HERE):
            item.add_marker(pytest.mark.reliability)
