"""``proto/conformance.py``, the scripted session CONFORMANCE.md asks for, passes
against a real server (loopback, the real ONNX engine, 8 samples): the script and the
server keep each other honest."""

from __future__ import annotations

import asyncio

import pytest

from tests.online.conftest import SECRET, make_cfg
from tests.online.wsclient import Factory, serving
from tests.proto.helpers import load

pytestmark = pytest.mark.timeout(60)


def test_the_conformance_session_passes(engine_factory: Factory) -> None:
    conformance = load("conformance")
    passed: list[str] = []

    async def scenario() -> None:
        async with serving(make_cfg(lookahead=2), engine_factory) as server:
            await conformance.run(f"ws://127.0.0.1:{server.port}/", SECRET, passed.append)

    asyncio.run(scenario())
    assert len(passed) == 2 * 5 + 2, passed
