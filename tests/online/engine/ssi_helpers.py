"""Shared by the SSI engine's tests (test_ssi.py, test_ssi_frames.py): stub pools and
selectors, and helpers that run an engine and compare its poses."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from posecast.online.engine.ports import Pool, StepDecoder
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import PoseOut, TrackerFrame

MakeEngine = Callable[..., Engine]
WalkFrames = Callable[..., list[TrackerFrame]]


class Never:
    """A selector that always stays: holds a player on its first sample (no transitions)."""

    def choose(self, current: int, scores: np.ndarray, positions: np.ndarray) -> int | None:
        return None


class Forced:
    """Stay, except on call ``at`` (1-based): then move to ``to``, or, with ``to=None``, to
    the sample of least anomaly error among the others (what the anomaly selector picks)."""

    def __init__(self, at: int, to: int | None = None) -> None:
        self.at, self.to, self.calls = at, to, 0
        self.chosen: int | None = None

    def choose(self, current: int, scores: np.ndarray, positions: np.ndarray) -> int | None:
        self.calls += 1
        if self.calls != self.at:
            return None
        others = scores.astype(np.float64).copy()
        others[current] = np.inf
        self.chosen = int(np.argmin(others)) if self.to is None else self.to
        return self.chosen


class RecordingPool:
    """The backend's pool, keeping the scores ``(P*N,)`` of the latest step."""

    def __init__(self, pool: Pool) -> None:
        self.pool, self.threshold_m = pool, pool.threshold_m
        self.last = np.zeros(0)

    def step(self, *args: Any) -> np.ndarray:
        scores: np.ndarray = self.pool.step(*args)
        self.last = scores.copy()
        return scores

    def emit(self, *args: Any) -> tuple[np.ndarray, np.ndarray]:
        return self.pool.emit(*args)

    def upper_body(self, *args: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.pool.upper_body(*args)

    def hinge(self, *args: Any) -> None:
        self.pool.hinge(*args)


class NoContacts:
    """The backend's decoder with its foot contacts forced to 0, so no contact IK runs
    and positions show the decoder's poses (and the SSI interpolation) alone."""

    def __init__(self, decoder: StepDecoder) -> None:
        self.decoder, self.meta, self.name = decoder, decoder.meta, decoder.name
        self.cache_width = decoder.cache_width

    def cache_latents(self, eps: np.ndarray) -> np.ndarray:
        return self.decoder.cache_latents(eps)

    def step(
        self,
        features: np.ndarray,
        group: int,
        cache: np.ndarray,
        h: np.ndarray,
        out: Mapping[str, np.ndarray],
    ) -> None:
        self.decoder.step(features, group, cache, h, out)
        out["contacts"][...] = 0.0


def run(engine: Engine, frames: dict[str, list[TrackerFrame]]) -> dict[str, list[PoseOut]]:
    """Push every player's next frame and tick, until the longest walk is through."""
    out: dict[str, list[PoseOut]] = {pid: [] for pid in frames}
    for t in range(max(len(f) for f in frames.values())):
        for pid, fs in frames.items():
            if t < len(fs):
                engine.push(pid, fs[t])
        for pose in engine.tick().poses:
            out.setdefault(pose.player, []).append(pose)
    return out


def positions(poses: list[PoseOut]) -> np.ndarray:
    return np.array([p.positions for p in poses])


def max_joint_jumps(pos: np.ndarray) -> np.ndarray:
    """Largest joint displacement between consecutive frames ``(F-1,)``, metres."""
    out: np.ndarray = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(axis=-1)
    return out


def assert_same_poses(a: list[PoseOut], b: list[PoseOut], atol: float = 0.0) -> None:
    assert len(a) == len(b)
    assert [(p.seq, p.sample, p.transitioning, p.held) for p in a] == [
        (p.seq, p.sample, p.transitioning, p.held) for p in b
    ]
    for name in ("positions", "rotations", "contacts"):
        np.testing.assert_allclose(
            np.array([getattr(p, name) for p in a]),
            np.array([getattr(p, name) for p in b]),
            atol=atol,
            rtol=0.0,
            err_msg=name,
        )
