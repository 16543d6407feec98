"""The reliability suite (docs/reliability.md): load, faults and hostile input against
real processes on loopback. Every test here carries the ``reliability`` marker, so
``pytest -m reliability`` runs just this suite (the CI subset; the long runs are
commands in docs/reliability.md)."""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if "tests/reliability/" in str(item.path).replace("\\", "/"):
            item.add_marker(pytest.mark.reliability)
