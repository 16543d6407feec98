"""Capture to display, pose by pose, split into where the time went (pure).

For a pose of sender ``s`` made from its tracker frame ``seq``, on one host clock
(``CLOCK_MONOTONIC``, which the server's pose times are on too):

* ``capture``: when the sender sampled the frame (the frame's ``t``);
* ``pose_t``: the server time of the tick that emitted the pose (``pose.t``, the
  engine step's start);
* ``received``: when the receiving SDK handed the pose to the application;
* ``shown``: the first display frame that showed it (:mod:`.display`).

With ``lookahead_s`` the server's look-ahead (``welcome.lookahead_frames / rate_hz``)
and ``tick_s`` the mean engine step (``posecast_tick_seconds`` over the window), the
total ``shown - capture`` is the sum of

=================  =========================================================  ==========
component          what                                                       from
=================  =========================================================  ==========
look-ahead         the frames the engine holds a pose back, by design         welcome
server queue+tick  the rest of the frame's time in the server: the uplink     pose.t,
                   (loopback), its wait in the frame queue for a tick, the    /metrics
                   tick's step: ``pose_t + tick_s - capture - lookahead_s``
transport          routing and writing the tick's poses, the loopback, the    pose.t,
                   SDK's decoding: ``received - pose_t - tick_s``             /metrics
client buffer      the interpolator's render delay: ``shown - received``      client
=================  =========================================================  ==========

so the components add up to the total for every pose (their means to the mean; their
percentiles need not).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from posecast.offline.evaluation.latency.display import Displayed

COMPONENTS = ("lookahead", "server_queue_tick", "transport", "client_buffer")


@dataclass(frozen=True)
class Budget:
    """Per pose, seconds: the total and each of :data:`COMPONENTS`, ``(P,)`` each."""

    total: np.ndarray
    parts: dict[str, np.ndarray]

    @property
    def count(self) -> int:
        return len(self.total)


def budget(
    displayed: Iterable[Displayed],
    captures: Mapping[str, Mapping[int, float]],
    *,
    lookahead_s: float,
    tick_s: float,
    window: tuple[float, float],
) -> Budget:
    """The budget of every displayed pose whose frame was captured in ``window``
    (client time ``[start, end)``); ``captures[sender][seq]`` is the frame's capture
    time. A pose whose frame is unknown (sent before the record began) is left out."""
    rows = []
    for d in displayed:
        at = captures.get(d.sender, {}).get(d.seq)
        if at is not None and window[0] <= at < window[1]:
            rows.append((at, d.t, d.received, d.shown))
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)  # (P, 4)
    capture, pose_t, received, shown = a.T  # (P,) each
    parts = {
        "lookahead": np.full(len(a), lookahead_s),
        "server_queue_tick": pose_t + tick_s - capture - lookahead_s,
        "transport": received - pose_t - tick_s,
        "client_buffer": shown - received,
    }
    return Budget(shown - capture, parts)


def stats_ms(x: np.ndarray) -> dict[str, float | None]:
    """p50, p99, mean and max of seconds ``x``, in milliseconds (``None`` when empty)."""
    if len(x) == 0:
        return {"p50": None, "p99": None, "mean": None, "max": None}
    ms = np.asarray(x) * 1000.0
    return {
        "p50": round(float(np.percentile(ms, 50)), 2),
        "p99": round(float(np.percentile(ms, 99)), 2),
        "mean": round(float(ms.mean()), 2),
        "max": round(float(ms.max()), 2),
    }


def summary(b: Budget) -> dict[str, Any]:
    """The report's figures of one run: the total's p50, p99 and mean in ms, and the
    same for every component."""
    total = stats_ms(b.total)
    return {
        "capture_to_display_ms_p50": total["p50"],
        "capture_to_display_ms_p99": total["p99"],
        "capture_to_display_ms_mean": total["mean"],
        "capture_to_display_ms_max": total["max"],
        "components_ms": {name: stats_ms(b.parts[name]) for name in COMPONENTS},
        "poses_displayed": b.count,
    }
