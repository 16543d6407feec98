"""The forecast through the SDK against a real ``posecast serve --dev``: a client that
joins with ``forecast_ms=67`` gets every pose 4 ticks ahead (its ``t`` 66.7 ms past the
same pose's for a client without one), predicted: closer to where the body is 4 frames
later than the pose itself; ``set_forecast`` changes or ends it; out of range is
refused by the SDK, and by the server (``OUT_OF_RANGE``) when sent anyway."""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any

import numpy as np
import pytest

import posecast_client as pc
from sdk_helpers import DevServer, EventLog, for_seconds

TICK = 1 / 60


def run(coro: Coroutine[Any, Any, None], timeout_s: float = 60.0) -> None:
    asyncio.run(asyncio.wait_for(coro, timeout_s))


def _poses(events: list[pc.Event], player: str) -> dict[int, pc.Pose]:
    return {e.seq: e for e in events if isinstance(e, pc.Pose) and e.player == player}


def _mean_error(a: dict[int, pc.Pose], b: dict[int, pc.Pose], seqs: list[int]) -> float:
    """Mean joint distance of ``a[s]`` from ``b[s + 4]`` (the body 4 frames on)."""
    d = [np.linalg.norm(a[s].positions - b[s + 4].positions, axis=-1).mean() for s in seqs]
    return float(np.mean(d))


def test_a_forecast_client_gets_poses_predicted_4_ticks_ahead(
    dev_server: DevServer, uid: str
) -> None:
    room = f"fc-{uid}"
    ada_id = f"ada-{uid}"

    async def main() -> None:
        ada = await pc.connect(dev_server.url, dev_server.token(room, ada_id))
        now = await pc.connect(dev_server.url, dev_server.token(room, f"now-{uid}", "spectator"))
        ahead = await pc.connect(dev_server.url, dev_server.token(room, f"fc-{uid}", "spectator"))
        async with ada, now, ahead:
            await ada.join(room, "Ada")
            await now.join(room, "Now")
            w = await ahead.join(room, "Ahead", forecast_ms=67.0)
            assert w.forecast_ms == pytest.approx(4000 / 60)
            logs = EventLog(now), EventLog(ahead)
            source = pc.WalkSource(seconds=10.0, seed=3)
            await ada.stream(for_seconds(source, 3.0))
            await asyncio.sleep(0.3)
            on_until = len(logs[1].events)
            await ahead.set_forecast(0.0)  # off: the poses of their own tick again
            await asyncio.sleep(0.3)
            off_from = len(logs[1].events)
            await ada.stream(for_seconds(source, 1.0))
            await asyncio.sleep(0.3)
            for log in logs:
                log.stop()
            plain = _poses(logs[0].events, ada_id)
            fc = _poses(logs[1].events[:on_until], ada_id)
            both = sorted(set(plain) & set(fc))
            assert len(both) > 60, len(both)
            skew = [fc[s].t - plain[s].t for s in both]
            assert np.allclose(skew, 4 * TICK, atol=1e-6), (min(skew), max(skew))
            # predicted, not held: nearer the body 4 frames on than the pose itself
            later = [s for s in both if both[0] + 3 < s <= both[-1] - 4 and s + 4 in plain]
            assert len(later) > 20, len(later)
            held, pred = _mean_error(plain, plain, later), _mean_error(fc, plain, later)
            assert pred < 0.5 * held, (pred, held)
            off = _poses(logs[1].events[off_from:], ada_id)
            same = sorted(set(off) & set(plain))
            assert len(same) > 20 and all(abs(off[s].t - plain[s].t) < 1e-9 for s in same)

    run(main())


def test_out_of_range_forecasts_are_refused(dev_server: DevServer, uid: str) -> None:
    room = f"fcbad-{uid}"

    async def main() -> None:
        c = await pc.connect(dev_server.url, dev_server.token(room, f"c-{uid}", "spectator"))
        async with c:
            with pytest.raises(ValueError, match="forecast_ms"):
                await c.join(room, "C", forecast_ms=150.0)  # nothing sent
            await c.join(room, "C", forecast_ms=33.0)
            log = EventLog(c)
            for bad in (100.5, -1.0, float("nan")):
                with pytest.raises(ValueError, match="forecast_ms"):
                    await c.set_forecast(bad)
            await c.send(pc.Forecast(101.0))  # sent anyway: the server refuses it
            err = await log.wait_for(lambda e: isinstance(e, pc.Error))
            assert isinstance(err, pc.Error) and err.code == "OUT_OF_RANGE"
            assert err.field == "ms" and not err.fatal
            log.stop()

    run(main())
