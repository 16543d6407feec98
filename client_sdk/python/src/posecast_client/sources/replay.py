"""Replayed motion as a headset: the built-in walk, or a BVH clip, at 60 Hz.

:class:`BvhReplaySource` places the four trackers exactly **at BVH joints** - no
retargeting, no body-size correction: the head tracker at the head joint, the hand
trackers at the hand joints (the wrists) and the waist tracker at the hips joint,
each with that joint's world rotation. Joints are found by name (:data:`RIGS`):

=========  ========================  ========  ====================================
rig        head, hands, waist        unit      first frame
=========  ========================  ========  ====================================
posecast   HEAD LEFT_HAND RIGHT_HAND  1 m       motion (posecast's own BVH export)
           PELVIS
cmu_mb     Head LeftHand RightHand   0.056444  a T-pose, skipped (cgspeed MotionBuilder
           Hips                      m         release of the CMU database)
cmu_daz    head lHand rHand hip      0.01 m    a T-pose, skipped (cgspeed Daz release)
=========  ========================  ========  ====================================

Positions are scaled to metres by the rig's unit; the world frame is BVH's (+Y up;
the canonical and CMU rigs face +Z). Clips are resampled to ``rate_hz`` (linear
positions, normalised-lerp rotations).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from posecast_client.bvh import read_bvh
from posecast_client.errors import BvhError
from posecast_client.rotations import F64, fk, mat2quat, quat2mat, quat_mul, quat_nlerp
from posecast_client.skeleton import PARENTS, TRACKER_JOINTS, reference_offsets
from posecast_client.sources.base import TrackerSample, TrackerSource
from posecast_client.sources.walk import walk_motion


@dataclass(frozen=True)
class BvhRig:
    """Where the trackers sit in one BVH layout: joint names in slot order (head, left
    hand, right hand, waist), the file's length unit, and whether frame 0 is a T-pose."""

    name: str
    joints: tuple[str, str, str, str]
    unit_m: float
    first_frame_is_tpose: bool


RIGS: tuple[BvhRig, ...] = (
    BvhRig("posecast", ("HEAD", "LEFT_HAND", "RIGHT_HAND", "PELVIS"), 1.0, False),
    BvhRig("cmu_mb", ("Head", "LeftHand", "RightHand", "Hips"), 0.056444, True),
    BvhRig("cmu_daz", ("head", "lHand", "rHand", "hip"), 0.01, True),
)


class ReplaySource(TrackerSource):
    """Replays tracker arrays as a live headset, paced in real time.

    Args:
        positions: ``(F, 4, 3)`` metres; orientations: ``(F, 4, 4)`` xyzw; slot order.
        fps: frame rate of the arrays.
        rate_hz: output rate (60, what the shipped model runs at).
        loop: start over at the end instead of stopping.
        noise_m: standard deviation of Gaussian position noise per axis, metres (0).
        noise_rad: standard deviation of random orientation noise, radians (0).
        dropout: fraction of the time each tracker is lost (0), in bursts of about
            ``dropout_burst_s`` seconds; a lost tracker's ``valid`` bit is clear.
        offset_m: added to every position (to place several players side by side).
        seed: seeds the noise and the dropouts.
    """

    def __init__(
        self,
        positions: ArrayLike,
        orientations: ArrayLike,
        fps: float,
        *,
        rate_hz: float = 60.0,
        loop: bool = False,
        noise_m: float = 0.0,
        noise_rad: float = 0.0,
        dropout: float = 0.0,
        dropout_burst_s: float = 0.2,
        offset_m: Sequence[float] = (0.0, 0.0, 0.0),
        seed: int = 0,
    ) -> None:
        if not 0.0 <= dropout < 1.0:
            raise ValueError("dropout must be in [0, 1)")
        pos = np.asarray(positions, dtype=np.float64)
        quat = np.asarray(orientations, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[1:] != (4, 3) or quat.shape != (len(pos), 4, 4):
            raise ValueError(f"need (F, 4, 3) and (F, 4, 4), got {pos.shape} and {quat.shape}")
        self.positions, self.orientations = _resample(pos, quat, fps, rate_hz)
        self.positions += np.asarray(offset_m, dtype=np.float64)
        self.rate_hz = rate_hz
        self.loop = loop
        self.noise_m, self.noise_rad = noise_m, noise_rad
        self.dropout, self.dropout_burst_s = dropout, dropout_burst_s
        self.seed = seed

    @property
    def n_frames(self) -> int:
        return len(self.positions)

    @property
    def seconds(self) -> float:
        return self.n_frames / float(self.rate_hz or 60.0)

    def samples(self) -> Iterator[TrackerSample]:
        """Every sample, unpaced and without times (endless when ``loop``)."""
        noise = np.random.default_rng([self.seed, 0])  # separate streams: the dropouts
        drops = np.random.default_rng([self.seed, 1])  # do not change with the noise
        frames = max(1.0, self.dropout_burst_s * float(self.rate_hz or 60.0))
        p_recover = 1.0 / frames
        p_lose = self.dropout / (1.0 - self.dropout) * p_recover  # the lost fraction is `dropout`
        lost = np.zeros(4, dtype=bool)
        while True:
            for pos, quat in zip(self.positions, self.orientations, strict=True):
                if self.noise_m > 0:
                    pos = pos + noise.normal(0.0, self.noise_m, pos.shape)
                if self.noise_rad > 0:
                    turn = _small_rotation(noise.normal(0.0, self.noise_rad, (4, 3)))
                    quat = quat_mul(turn, quat)
                if self.dropout > 0:
                    u = drops.random(4)
                    lost = np.where(lost, u >= p_recover, u < p_lose)
                valid = int(sum(1 << i for i in range(4) if not lost[i]))
                yield TrackerSample(pos.copy(), quat.copy(), valid)
            if not self.loop:
                return

    async def __aiter__(self) -> AsyncIterator[TrackerSample]:
        """Samples at ``rate_hz`` on the host clock, each stamped with its send time."""
        period = 1.0 / float(self.rate_hz or 60.0)
        start, k = time.monotonic(), 0
        for s in self.samples():
            due = start + k * period
            now = time.monotonic()
            if due > now:
                await asyncio.sleep(due - now)
            elif now - due > 0.25:  # stalled (a debugger, a busy loop): do not catch up
                start, k = now - k * period, k
            yield TrackerSample(s.positions, s.orientations, s.valid, t=time.monotonic())
            k += 1


class WalkSource(ReplaySource):
    """The built-in fixture: the procedural walk of :mod:`posecast_client.sources.walk`.

    Args:
        seconds: clip length (10 s); ``loop=True`` repeats it.
        seed: varies stride, speed and style of the walk (and seeds noise/dropouts).
        Other keyword arguments: as :class:`ReplaySource`.
    """

    def __init__(
        self, seconds: float = 10.0, *, seed: int = 0, rate_hz: float = 60.0, **kw: Any
    ) -> None:
        root, local = walk_motion(seconds, rate_hz, seed)
        pos, quat = _trackers_from_canonical(root, local)
        super().__init__(pos, quat, rate_hz, rate_hz=rate_hz, seed=seed, **kw)


class BvhReplaySource(ReplaySource):
    """A BVH clip replayed as a headset; see the module docstring for where trackers sit.

    Args:
        path: a ``.bvh`` or gzip-compressed BVH file.
        rig: the layout; by default the first of :data:`RIGS` whose joints all exist.
        unit_m: metres per file unit, overriding the rig's.
        Other keyword arguments: as :class:`ReplaySource`.

    Raises:
        BvhError: the file is not BVH, or no rig's joints are in it.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        rig: BvhRig | None = None,
        unit_m: float | None = None,
        **kw: Any,
    ) -> None:
        bvh = read_bvh(path)
        if rig is None:
            rig = next((r for r in RIGS if set(r.joints) <= set(bvh.names)), None)
            if rig is None:
                raise BvhError(
                    "no known rig: need joints " + " / ".join(",".join(r.joints) for r in RIGS),
                    file=str(path),
                )
        self.rig = rig
        world, pos = bvh.fk(rig.unit_m if unit_m is None else unit_m)
        idx = [bvh.names.index(name) for name in rig.joints]
        first = 1 if rig.first_frame_is_tpose and bvh.n_frames > 1 else 0
        fps = 1.0 / bvh.frame_time_s
        if abs(fps - round(fps)) <= 1e-4 * fps:  # files store 1/120 as 0.0083333
            fps = float(round(fps))
        super().__init__(pos[first:, idx], mat2quat(world[first:, idx]), fps, **kw)


def _trackers_from_canonical(root: F64, local_quat: F64) -> tuple[F64, F64]:
    """Trackers on the canonical skeleton: ``(F, 4, 3)`` positions, ``(F, 4, 4)`` xyzw."""
    world, pos = fk(quat2mat(local_quat), root, reference_offsets(), PARENTS)
    idx = [int(j) for j in TRACKER_JOINTS]
    return pos[:, idx], mat2quat(world[:, idx])


def _small_rotation(rotvec: F64) -> F64:
    """Axis-angle vectors ``(..., 3)`` -> quaternions ``(..., 4)``."""
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    axis = rotvec / np.maximum(angle, 1e-12)
    return np.concatenate([axis * np.sin(angle / 2), np.cos(angle / 2)], axis=-1)


def _resample(pos: F64, quat: F64, fps: float, rate_hz: float) -> tuple[F64, F64]:
    """Arrays at ``fps`` -> arrays at ``rate_hz`` over the same duration."""
    if abs(fps - rate_hz) < 1e-9 or len(pos) < 2:
        return pos.copy(), quat.copy()
    x = np.arange(int(np.floor((len(pos) - 1) * rate_hz / fps)) + 1) * (fps / rate_hz)
    i = np.minimum(x.astype(int), len(pos) - 2)
    w = (x - i)[:, None, None]  # (N, 1, 1)
    out_pos = pos[i] * (1 - w) + pos[i + 1] * w
    return out_pos, quat_nlerp(quat[i], quat[i + 1], w[..., 0])
