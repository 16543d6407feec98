"""Metrics (posecast.online.metrics)."""

from __future__ import annotations

import asyncio

from posecast.online.metrics import Metrics


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
