"""Fixtures shared by the SDK tests (helpers live in ``sdk_helpers.py``)."""

from __future__ import annotations

import secrets
from collections.abc import Iterator

import numpy as np
import pytest

from sdk_helpers import DevServer, dev_server_at


@pytest.fixture(scope="session")
def dev_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DevServer]:
    """One server shared by the tests that do not stop it."""
    with dev_server_at(tmp_path_factory.mktemp("server") / "server.log") as server:
        yield server


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh generator with a fixed seed: every run sees the same numbers."""
    return np.random.default_rng(20240611)


@pytest.fixture
def uid() -> str:
    """A fresh suffix for room and player ids (ids are never reused by a server)."""
    return secrets.token_hex(3)
