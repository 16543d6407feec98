"""The jitter buffer's rules as first written, one pose at a time: the reference the
batched :class:`posecast_client.interp.Interpolator` is compared with
(``test_interp_batch.py``).

The SDK's buffer plans a display frame's samples without touching an array, makes the
samples of every player in one batch, reuses the last frame's sample where no pose
changed it, and ends a fading correction once it is under 1e-12. This one does none
of that: each query samples rules 1 to 4 afresh, and rule 5 recomputes what the last
frame would show with today's poses every frame (as before issue 38's profiling).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from posecast_client.interp import (
    DEFAULT_INTERP,
    F64,
    ROOT,
    InterpConfig,
    InterpolatedPose,
    Mode,
    PoseLike,
    quat_slerp,
)
from posecast_client.protocol import seq_delta
from posecast_client.render_delay import RenderDelay
from posecast_client.rotations import quat_mul

_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
_CONJ = np.array([-1.0, -1.0, -1.0, 1.0])


@dataclass
class _Entry:
    t: float
    seq: int
    keyframe: bool
    positions: F64
    rotations: F64 | None
    seen: bool = False


class ReferenceBuffer:
    """One player's buffer, the rules of ``posecast_client.interp`` applied literally."""

    def __init__(self, config: InterpConfig = DEFAULT_INTERP) -> None:
        self.config = config
        self.player: str | None = None
        self._entries: list[_Entry] = []
        self._times: list[float] = []
        self._last: InterpolatedPose | None = None
        self._unseen = 0
        self._delay = RenderDelay(
            start_s=config.delay_s,
            min_s=config.min_delay_s,
            max_s=config.max_delay_s,
            quantile=config.delay_quantile,
            window=config.delay_window,
            margin_s=config.delay_margin_s,
            slew=config.delay_slew,
        )

    @property
    def delay_s(self) -> float:
        return self._delay.delay_s if self.config.adaptive else self.config.delay_s

    def push(self, pose: PoseLike, *, keyframe: bool = False) -> bool:
        t = float(pose.t)
        if not math.isfinite(t):
            return False
        i = bisect.bisect_left(self._times, t)
        if i < len(self._times) and self._times[i] == t:
            return False
        if i == 0 and len(self._entries) >= self.config.capacity:
            return False
        rot = None if pose.rotations is None else np.array(pose.rotations, dtype=np.float64)
        entry = _Entry(t, int(pose.seq), keyframe, np.array(pose.positions, dtype=np.float64), rot)
        self.player = pose.player
        self._entries.insert(i, entry)
        self._times.insert(i, t)
        self._unseen += 1
        if len(self._entries) > self.config.capacity:
            self._unseen -= not self._entries[0].seen
            del self._entries[0], self._times[0]
        return True

    def pose_at(self, time: float) -> InterpolatedPose | None:
        if self.config.adaptive:
            self._observe(time)
            self._delay.advance(time)
        tau = time - self.delay_s
        raw = self._raw(tau)
        last, self._last = self._last, None
        if raw is None:
            return None
        shown = raw
        if last is not None and self._blends(last.t, tau):
            before = self._raw(last.t)
            assert before is not None
            k = math.exp(-(tau - last.t) / self.config.correction_s)
            pos = raw.positions + (last.positions - before.positions) * k
            rot = raw.rotations
            if rot is not None and last.rotations is not None and before.rotations is not None:
                off = quat_mul(last.rotations, before.rotations * _CONJ)
                rot = quat_mul(quat_slerp(_IDENTITY, off, k), rot)
            shown = InterpolatedPose(raw.player, tau, raw.seq, pos, rot, raw.mode)
        self._last = shown
        return shown

    def _observe(self, time: float) -> None:
        if self._unseen == 0:
            return
        gap = self.config.gap_s
        measures = self._delay.measures(time, gap)
        for k, e in enumerate(self._entries):
            if e.seen:
                continue
            e.seen = True
            if measures and k > 0 and e.t - self._times[k - 1] <= gap:
                self._delay.observe(time - self._times[k - 1])
        self._unseen = 0

    def _blends(self, last_tau: float, tau: float) -> bool:
        if self.config.correction_s == 0.0 or not 0.0 < tau - last_tau <= self.config.gap_s:
            return False
        lo = bisect.bisect_right(self._times, last_tau)
        hi = bisect.bisect_right(self._times, tau)
        return not any(
            k > 0 and self._snaps(self._entries[k - 1], self._entries[k])
            for k in range(max(lo, 1), hi)
        )

    def _raw(self, tau: float) -> InterpolatedPose | None:
        if not self._entries:
            return None
        i = bisect.bisect_right(self._times, tau) - 1
        if i < 0:
            return self._hold(self._entries[0], tau)
        a = self._entries[i]
        if i + 1 < len(self._entries):
            b = self._entries[i + 1]
            if not self._snaps(a, b):
                u = (tau - a.t) / (b.t - a.t)
                pos = a.positions + (b.positions - a.positions) * u
                rot = None
                if a.rotations is not None and b.rotations is not None:
                    rot = quat_slerp(a.rotations, b.rotations, u)
                return self._sample(a, tau, pos, "interpolate", rot)
        p = self._entries[i - 1] if i > 0 else None
        if p is None or self._snaps(p, a) or self.config.max_extrapolate_s == 0.0:
            return self._hold(a, tau)
        ahead = tau - a.t
        mode: Mode = "extrapolate" if ahead <= self.config.max_extrapolate_s else "hold"
        s = min(ahead, self.config.max_extrapolate_s) / (a.t - p.t)
        pos = a.positions + (a.positions - p.positions) * s
        rot = None
        if a.rotations is not None and p.rotations is not None:
            rot = quat_slerp(p.rotations, a.rotations, 1.0 + s)
        return self._sample(a, tau, pos, mode, rot)

    def _snaps(self, a: _Entry, b: _Entry) -> bool:
        cfg = self.config
        if b.t - a.t > cfg.gap_s:
            return True
        if b.keyframe and seq_delta(b.seq, a.seq) <= 0:
            return True
        jump = float(np.linalg.norm(b.positions[ROOT] - a.positions[ROOT]))
        return jump > cfg.teleport_m

    def _hold(self, a: _Entry, tau: float) -> InterpolatedPose:
        rot = None
        if a.rotations is not None:
            rot = a.rotations / np.linalg.norm(a.rotations, axis=-1, keepdims=True)
        return self._sample(a, tau, a.positions.copy(), "hold", rot)

    def _sample(
        self, a: _Entry, tau: float, pos: F64, mode: Mode, rot: F64 | None = None
    ) -> InterpolatedPose:
        return InterpolatedPose(self.player or "", tau, a.seq, pos, rot, mode)
