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

Given a ``tracker_set`` (:mod:`posecast_client.sites`), a source yields one row per
site of the set instead of the four slots, each at its joint (feet at the ankles,
knees at the top of the shins, elbows at the top of the forearms: the rigs'
``LeftFoot``/``lFoot``, ``LeftLeg``/``lShin``, ``LeftForeArm``/``lForeArm``), and an
inertial site reports its world acceleration, the central second difference of the
joint's position at ``rate_hz`` (m/s^2, the first and last frames repeat their
neighbours'), with the joint's orientation: a synthetic IMU.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from posecast_client.bvh import read_bvh
from posecast_client.errors import BvhError
from posecast_client.protocol import MAX_COORD_M
from posecast_client.rotations import F64, fk, mat2quat, quat2mat, quat_mul, quat_nlerp
from posecast_client.sites import MAX_SITES, SITES, TrackerSet, as_tracker_set
from posecast_client.skeleton import PARENTS, TRACKER_JOINTS, reference_offsets
from posecast_client.sources.base import TrackerSample, TrackerSource
from posecast_client.sources.walk import walk_motion


@dataclass(frozen=True)
class BvhRig:
    """Where the trackers sit in one BVH layout: joint names in slot order (head, left
    hand, right hand, waist), the file's length unit, whether frame 0 is a T-pose, and
    the joints of the other sites of a tracker set (feet, knees, elbows, left first)."""

    name: str
    joints: tuple[str, str, str, str]
    unit_m: float
    first_frame_is_tpose: bool
    limbs: tuple[str, str, str, str, str, str] | None = None

    def site_joint(self, site: str) -> str:
        """The file's joint a tracker set's ``site`` sits on."""
        names: dict[str, str] = dict(zip(SITES, (*self.joints, *(self.limbs or ())), strict=False))
        if site not in names:
            raise BvhError(f"rig {self.name} has no joint for site {site!r}")
        return names[site]


RIGS: tuple[BvhRig, ...] = (
    BvhRig(
        "posecast",
        ("HEAD", "LEFT_HAND", "RIGHT_HAND", "PELVIS"),
        1.0,
        False,
        ("LEFT_FOOT", "RIGHT_FOOT", "LEFT_SHIN", "RIGHT_SHIN", "LEFT_FOREARM", "RIGHT_FOREARM"),
    ),
    BvhRig(
        "cmu_mb",
        ("Head", "LeftHand", "RightHand", "Hips"),
        0.056444,
        True,
        ("LeftFoot", "RightFoot", "LeftLeg", "RightLeg", "LeftForeArm", "RightForeArm"),
    ),
    BvhRig(
        "cmu_daz",
        ("head", "lHand", "rHand", "hip"),
        0.01,
        True,
        ("lFoot", "rFoot", "lShin", "rShin", "lForeArm", "rForeArm"),
    ),
)


class ReplaySource(TrackerSource):
    """Replays tracker arrays as a live headset, paced in real time.

    Args:
        positions: ``(F, 4, 3)`` metres; orientations: ``(F, 4, 4)`` xyzw; slot order
            (or ``(F, n, 3)`` / ``(F, n, 4)``: the sites of a tracker set, in its order).
        fps: frame rate of the arrays.
        rate_hz: output rate (60, what the shipped model runs at).
        loop: start over at the end instead of stopping.
        inertial: per row, whether it is an inertial site: its positions become
            world accelerations (m/s^2) after resampling (none by default).
        noise_m: standard deviation of Gaussian position noise per axis, metres (0;
            positional rows only).
        noise_rad: standard deviation of random orientation noise, radians (0).
        dropout: fraction of the time each tracker is lost (0), in bursts of about
            ``dropout_burst_s`` seconds; a lost tracker's ``valid`` bit is clear, as is
            that of a row beyond +-1000 (m, or m/s^2: a glitch in a clip's motion),
            which the server would refuse.
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
        inertial: Sequence[bool] | None = None,
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
        n = pos.shape[1] if pos.ndim == 3 else 0
        if not 1 <= n <= MAX_SITES or pos.shape[2:] != (3,) or quat.shape != (len(pos), n, 4):
            raise ValueError(f"need (F, n, 3) and (F, n, 4), got {pos.shape} and {quat.shape}")
        self.inertial = np.zeros(n, bool) if inertial is None else np.array(inertial, bool)
        if self.inertial.shape != (n,):
            raise ValueError(f"inertial needs one flag per row ({n})")
        self.positions, self.orientations = _resample(pos, quat, fps, rate_hz)
        positional = ~self.inertial
        self.positions[:, positional] += np.asarray(offset_m, dtype=np.float64)
        if self.inertial.any():
            acc = _second_difference(self.positions[:, self.inertial], float(rate_hz or 60.0))
            self.positions[:, self.inertial] = acc
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
        n = self.positions.shape[1]
        positional = ~self.inertial[:, None]
        lost = np.zeros(n, dtype=bool)
        while True:
            for pos, quat in zip(self.positions, self.orientations, strict=True):
                if self.noise_m > 0:
                    pos = pos + noise.normal(0.0, self.noise_m, pos.shape) * positional
                if self.noise_rad > 0:
                    turn = _small_rotation(noise.normal(0.0, self.noise_rad, (n, 3)))
                    quat = quat_mul(turn, quat)
                if self.dropout > 0:
                    u = drops.random(n)
                    lost = np.where(lost, u >= p_recover, u < p_lose)
                shown = ~lost & (np.abs(pos) <= MAX_COORD_M).all(axis=1)  # else refused
                valid = int(sum(1 << i for i in range(n) if shown[i]))
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
        tracker_set: yield the sites of this set (a layout string or a
            :class:`~posecast_client.sites.TrackerSet`) instead of the four slots.
        Other keyword arguments: as :class:`ReplaySource`.
    """

    def __init__(
        self,
        seconds: float = 10.0,
        *,
        seed: int = 0,
        rate_hz: float = 60.0,
        tracker_set: str | TrackerSet | None = None,
        **kw: Any,
    ) -> None:
        root, local = walk_motion(seconds, rate_hz, seed)
        ts = as_tracker_set(tracker_set)
        joints = TRACKER_JOINTS if ts is None else ts.joints
        pos, quat = trackers_from_canonical(root, local, joints)
        inertial = None if ts is None else ts.inertial
        self.tracker_set = ts
        super().__init__(pos, quat, rate_hz, rate_hz=rate_hz, seed=seed, inertial=inertial, **kw)


class BvhReplaySource(ReplaySource):
    """A BVH clip replayed as a headset; see the module docstring for where trackers sit.

    Args:
        path: a ``.bvh`` or gzip-compressed BVH file.
        rig: the layout; by default the first of :data:`RIGS` whose joints all exist.
        unit_m: metres per file unit, overriding the rig's.
        tracker_set: yield the sites of this set (a layout string or a
            :class:`~posecast_client.sites.TrackerSet`) instead of the four slots.
        Other keyword arguments: as :class:`ReplaySource`.

    Raises:
        BvhError: the file is not BVH, no rig's joints are in it, or its Frame Time is
            over 1 s (or infinite).
        ValueError: ``tracker_set`` names no tracker set.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        rig: BvhRig | None = None,
        unit_m: float | None = None,
        tracker_set: str | TrackerSet | None = None,
        **kw: Any,
    ) -> None:
        ts = as_tracker_set(tracker_set)
        bvh = read_bvh(path)
        if rig is None:
            rig = next((r for r in RIGS if set(r.joints) <= set(bvh.names)), None)
            if rig is None:
                raise BvhError(
                    "no known rig: need joints " + " / ".join(",".join(r.joints) for r in RIGS),
                    file=str(path),
                )
        self.rig = rig
        self.tracker_set = ts
        names = rig.joints if ts is None else tuple(rig.site_joint(s) for s in ts.sites)
        missing = [n for n in names if n not in bvh.names]
        if missing:
            raise BvhError(f"no joint {', '.join(missing)} (rig {rig.name})", file=str(path))
        world, pos = bvh.fk(rig.unit_m if unit_m is None else unit_m)
        idx = [bvh.names.index(name) for name in names]
        first = 1 if rig.first_frame_is_tpose and bvh.n_frames > 1 else 0
        fps = 1.0 / bvh.frame_time_s
        if not 1.0 <= fps < math.inf:  # resampling ~1/fps more frames, or 1/inf
            raise BvhError(
                f"Frame Time {bvh.frame_time_s} s: need at least 1 frame a second",
                file=str(path),
            )
        if abs(fps - round(fps)) <= 1e-4 * fps:  # files store 1/120 as 0.0083333
            fps = float(round(fps))
        inertial = None if ts is None else ts.inertial
        super().__init__(
            pos[first:, idx], mat2quat(world[first:, idx]), fps, inertial=inertial, **kw
        )


def trackers_from_canonical(
    root: F64, local_quat: F64, joints: Sequence[int] = TRACKER_JOINTS
) -> tuple[F64, F64]:
    """Trackers on ``joints`` of the canonical skeleton (the four slots by default):
    ``(F, n, 3)`` positions, ``(F, n, 4)`` xyzw."""
    world, pos = fk(quat2mat(local_quat), root, reference_offsets(), PARENTS)
    idx = [int(j) for j in joints]
    return pos[:, idx], mat2quat(world[:, idx])


def _second_difference(pos: F64, rate_hz: float) -> F64:
    """World accelerations ``(F, n, 3)`` of positions ``(F, n, 3)`` sampled at
    ``rate_hz``: the central second difference, the ends repeating their neighbours'."""
    acc = np.zeros_like(pos)
    if len(pos) >= 3:
        acc[1:-1] = (pos[2:] - 2.0 * pos[1:-1] + pos[:-2]) * rate_hz * rate_hz
        acc[0], acc[-1] = acc[1], acc[-2]
    return acc


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
