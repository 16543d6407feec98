"""Metrics (posecast.online.metrics) and JSON logs (posecast.online.shell.logging)."""

from __future__ import annotations

import asyncio
import io
import json
import logging
from collections.abc import Iterator

import pytest

from posecast.online.metrics import Metrics
from posecast.online.shell.logging import JsonFormatter, configure


def test_each_instance_owns_its_registry() -> None:
    a, b = Metrics(), Metrics()
    a.errors.labels("BAD_FIELD").inc()
    assert a.value("posecast_errors_total", {"code": "BAD_FIELD"}) == 1
    assert b.value("posecast_errors_total", {"code": "BAD_FIELD"}) == 0
    text = a.render().decode()
    for name in (
        "posecast_players",
        "posecast_rooms",
        "posecast_tick_seconds_bucket",
        "posecast_engine_batch_size_bucket",
        "posecast_ssi_transitions_total",
        "posecast_frames_dropped_total",
        "posecast_bytes_in_total",
        "posecast_bytes_out_total",
    ):
        assert name in text, name


def test_render_counts_the_event_loops_tasks() -> None:
    m = Metrics()
    m.render()  # no running loop: nothing counted, nothing raised
    assert m.value("posecast_asyncio_tasks") == 0

    async def main() -> tuple[float, float]:
        release = asyncio.Event()
        waiters = [asyncio.create_task(release.wait()) for _ in range(5)]
        await asyncio.sleep(0)
        m.render()
        busy = m.value("posecast_asyncio_tasks")
        release.set()
        await asyncio.gather(*waiters)
        m.render()
        return busy, m.value("posecast_asyncio_tasks")

    busy, idle = asyncio.run(main())
    assert (busy, idle) == (6, 1)  # the five waiters and main itself, then main alone
    assert "posecast_asyncio_tasks 1.0" in m.render().decode()


@pytest.fixture
def restore_logging() -> Iterator[None]:
    saved = {}
    for name in ("posecast", "websockets"):
        lg = logging.getLogger(name)
        saved[name] = (lg.handlers[:], lg.level, lg.propagate)
    yield
    for name, (handlers, level, propagate) in saved.items():
        lg = logging.getLogger(name)
        lg.handlers[:], lg.propagate = handlers, propagate
        lg.setLevel(level)


def test_json_lines_carry_the_extras(restore_logging: None) -> None:
    stream = io.StringIO()
    configure("INFO", stream)
    logging.getLogger("posecast.test").info("join", extra={"player": "p1", "room": "r"})
    logging.getLogger("posecast.test").debug("hidden")
    (line,) = stream.getvalue().splitlines()
    rec = json.loads(line)
    assert rec["event"] == "join" and rec["player"] == "p1" and rec["level"] == "INFO"


def test_exceptions_are_one_json_line() -> None:
    try:
        raise ValueError("boom")
    except ValueError:
        import sys

        rec = logging.LogRecord("x", logging.ERROR, "f", 1, "failed", None, sys.exc_info())
    out = json.loads(JsonFormatter().format(rec))
    assert out["event"] == "failed" and "ValueError: boom" in out["exc"]
