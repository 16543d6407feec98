"""How high real toes keep off the floor at each horizontal speed: the table behind the
engine's swing clearance (:mod:`posecast.body.clearance`).

For every frame of every clip, the toe's horizontal speed from the frame before and its
height now; per speed bin, a low percentile of the height. ``posecast data clearance
--data prepared`` prints it for the training split's ground truth.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from posecast.body.clearance import TOES, toe_steps

F64 = NDArray[np.floating]

# The bins whose centres are the engine's SPEEDS_M_S (m/s).
EDGES_M_S = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 6.0)


def toe_speed_height(positions: F64, fps: float) -> tuple[F64, F64]:
    """Both toes' horizontal speeds (m/s) from each frame to the next, and their heights
    at the later frame, flattened: ``(2 (T - 1),)`` each, for one clip ``(T, 19, 3)``."""
    height = np.asarray(positions, np.float64)[1:, TOES, 1]
    return toe_steps(positions, fps).ravel(), height.ravel()


def clearance_table(
    clips: Iterable[F64], fps: float, percentile: float = 5.0
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[int, ...]]:
    """``(centres, heights, counts)`` over ``clips`` (world positions ``(T, 19, 3)``):
    per bin of :data:`EDGES_M_S`, its centre, the ``percentile`` of the toe heights in it
    made non-decreasing with speed (a faster foot is not let nearer the floor than a
    slower one), and how many toe-frames it holds. A bin with no frame takes the one
    below it (0 for the first)."""
    pairs = [toe_speed_height(p, fps) for p in clips]
    speed = np.concatenate([s for s, _ in pairs]) if pairs else np.zeros(0)
    height = np.concatenate([h for _, h in pairs]) if pairs else np.zeros(0)
    edges = np.asarray(EDGES_M_S)
    centres = tuple(float(c) for c in (edges[:-1] + edges[1:]) / 2)
    heights: list[float] = []
    counts: list[int] = []
    for lo, hi in itertools.pairwise(edges):
        inside = height[(speed >= lo) & (speed < hi)]
        counts.append(int(inside.size))
        level = float(np.percentile(inside, percentile)) if inside.size else -np.inf
        heights.append(max([level, *heights[-1:]]) if heights else max(level, 0.0))
    return centres, tuple(round(h, 3) for h in heights), tuple(counts)
