"""Per-player calibration onto the canonical body (paper Sec. 4.4), and waist smoothing.

The network was trained on one body (head joint 1.60 m up). A user of another height
is scaled onto it: every tracker position is multiplied by ``scale`` on the way in,
and every output position divided by it on the way out, so the avatar stands where
the user stands at the user's size. A T-pose calibration also measures the waist
tracker's offset from where the canonical pelvis would be, in the waist's own frame,
and removes it from every later frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from posecast.errors import ConfigError
from posecast.geometry.rotations import (
    quat_apply,
    quat_conj,
    quat_identity,
    quat_mul,
    quat_normalize,
    quat_slerp,
    yaw2quat,
)
from posecast.skeleton import REST_PELVIS_HEIGHT_M, Joint, reference_offsets
from posecast.tracking.features import TrackerSlot

F64 = NDArray[np.float64]

# Head joint height of the reference body standing in its rest pose.
REFERENCE_HEAD_HEIGHT_M = REST_PELVIS_HEIGHT_M + float(
    reference_offsets()[[Joint.SPINE, Joint.CHEST, Joint.NECK, Joint.HEAD], 1].sum()
)
# The head joint sits this far below the top of the head on the reference body.
HEAD_TOP_ABOVE_JOINT_M = 0.15
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.9, 2.5
# A T-pose's hands at least this far apart horizontally: the heading is square to them.
MIN_TPOSE_HAND_SPAN_M = 0.5


@dataclass(frozen=True)
class Calibration:
    scale: float = 1.0  # canonical metres per user metre
    waist_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # in the waist's frame
    # Per slot, a rotation (xyzw) applied on the right of the reported orientation, so
    # that a device's own axes become the joint's (headset-only T-pose calibration).
    rot_offsets: tuple[tuple[float, float, float, float], ...] = ()

    @classmethod
    def from_height(cls, height_m: float) -> Calibration:
        """From the user's standing height (top of head), metres."""
        if not MIN_HEIGHT_M <= height_m <= MAX_HEIGHT_M:
            raise ConfigError(f"height {height_m} m outside [{MIN_HEIGHT_M}, {MAX_HEIGHT_M}]")
        return cls(scale=(REFERENCE_HEAD_HEIGHT_M + HEAD_TOP_ABOVE_JOINT_M) / height_m)

    @classmethod
    def from_tpose(cls, pos: F64, quat: F64, waist: bool = True) -> Calibration:
        """From one frame of the user standing in a T-pose: ``(4, 3)`` / ``(4, 4)``.

        ``waist=False`` (a headset-only player, whose model reads the head's and hands'
        orientations): the scale, and per-slot rotation offsets that turn each device's
        reported orientation into its joint's. In a T-pose every joint's world rotation
        is the body's heading alone, and the heading is square to the line from the
        right hand to the left."""
        scale = _tpose_scale(pos)
        if not waist:
            present = np.arange(len(pos)) < TrackerSlot.WAIST  # head and hands, no waist
            offsets = _rot_offsets(quat, _tpose_heading(pos), present)
            return cls(scale=scale, rot_offsets=offsets)
        waist_pos = pos[TrackerSlot.WAIST] * scale
        head = pos[TrackerSlot.HEAD] * scale
        # In a T-pose the pelvis stands under the head, at the reference pelvis height.
        expected = np.array([head[0], REST_PELVIS_HEIGHT_M, head[2]])
        offset = quat_apply(quat_conj(quat[TrackerSlot.WAIST]), waist_pos - expected)
        return cls(scale=scale, waist_offset_m=tuple(float(v) for v in offset))  # type: ignore[arg-type]

    @classmethod
    def from_tpose_sites(cls, pos: F64, quat: F64, kinds: NDArray[np.int8]) -> Calibration:
        """A tracker set's T-pose, one row per site (``(10, 3)`` / ``(10, 4)``, kinds
        ``(10,)``): the scale, and a rotation offset for every present site (positional
        or inertial) that turns its device's orientation into its joint's, as
        :meth:`from_tpose` does for a headset-only player's three. No waist position
        offset: a set's waist tracker is worn on the pelvis."""
        scale = _tpose_scale(pos)
        offsets = _rot_offsets(quat, _tpose_heading(pos), np.asarray(kinds) != 0)
        return cls(scale=scale, rot_offsets=offsets)

    def orient(self, quat: F64) -> F64:
        """Tracker orientations ``(4, 4)`` with the device offsets removed."""
        if not self.rot_offsets:
            return quat
        return quat_normalize(quat_mul(quat, np.asarray(self.rot_offsets)))

    def apply(self, pos: F64, quat: F64) -> F64:
        """Tracker positions ``(4, 3)`` in canonical-body metres."""
        out = pos * self.scale
        if any(self.waist_offset_m):
            out[TrackerSlot.WAIST] -= quat_apply(
                quat[TrackerSlot.WAIST], np.asarray(self.waist_offset_m)
            )
        return out


def _tpose_scale(pos: F64) -> float:
    """The scale a T-pose frame's head height gives (``ConfigError`` if implausible)."""
    head_y = float(pos[TrackerSlot.HEAD, 1])
    if not MIN_HEIGHT_M - HEAD_TOP_ABOVE_JOINT_M < head_y < MAX_HEIGHT_M:
        raise ConfigError(f"T-pose head height {head_y:.2f} m is implausible")
    return REFERENCE_HEAD_HEIGHT_M / head_y


def _tpose_heading(pos: F64) -> F64:
    """The body's heading (a yaw quaternion) in a T-pose: square to the line from the
    right hand to the left."""
    across = pos[TrackerSlot.LEFT_HAND] - pos[TrackerSlot.RIGHT_HAND]
    forward = np.cross(across, [0.0, 1.0, 0.0])  # left x up = forward (+Z)
    if np.hypot(forward[0], forward[2]) < MIN_TPOSE_HAND_SPAN_M:
        raise ConfigError("T-pose hands are not spread apart level with the body")
    return yaw2quat(np.arctan2(forward[0], forward[2]))


def _rot_offsets(
    quat: F64, heading: F64, present: NDArray[np.bool_]
) -> tuple[tuple[float, float, float, float], ...]:
    """Per row, the offset that turns a T-pose's reported orientation into its joint's
    (in a T-pose every joint's world rotation is the heading); identity where absent."""
    ident = quat_identity()
    rows = [
        quat_mul(quat_conj(quat[i]), heading) if present[i] else ident for i in range(len(quat))
    ]
    return tuple(tuple(map(float, q)) for q in rows)  # type: ignore[misc]


def orient_all(calibrations: Sequence[Calibration], quat: F64) -> F64:
    """:meth:`Calibration.orient` of ``M`` players at once: ``quat (M, 4, 4)``, row ``i``
    by ``calibrations[i]``, with the same arithmetic (so the same bits) as one by one."""
    rows = [i for i, c in enumerate(calibrations) if c.rot_offsets]
    if not rows:
        return quat
    out = quat.copy()
    offsets = np.array([calibrations[i].rot_offsets for i in rows])  # (m, 4, 4)
    out[rows] = quat_normalize(quat_mul(quat[rows], offsets))
    return out


def apply_all(calibrations: Sequence[Calibration], pos: F64, quat: F64) -> F64:
    """:meth:`Calibration.apply` of ``M`` players at once: ``pos (M, 4, 3)``,
    ``quat (M, 4, 4)``, row ``i`` by ``calibrations[i]``, bit for bit as one by one."""
    out: F64 = pos * np.array([c.scale for c in calibrations])[:, None, None]
    rows = [i for i, c in enumerate(calibrations) if any(c.waist_offset_m)]
    if rows:
        offsets = np.array([calibrations[i].waist_offset_m for i in rows])  # (m, 3)
        out[rows, TrackerSlot.WAIST] -= quat_apply(quat[rows, TrackerSlot.WAIST], offsets)
    return out


def recalibrate(old: Calibration, new: Calibration, pos: F64, quat: F64) -> tuple[F64, F64]:
    """Frames ``pos (F, rows, 3)`` / ``quat (F, rows, 4)`` that ``old`` calibrated
    (:func:`orient_all`, then :func:`apply_all`), as ``new`` calibrates them: ``old``
    taken off, then ``new`` applied by the same two functions."""
    raw_q = quat
    if old.rot_offsets:
        raw_q = quat_mul(quat, quat_conj(np.asarray(old.rot_offsets)))
    raw = np.array(pos, dtype=np.float64, copy=True)
    if any(old.waist_offset_m):
        raw[:, TrackerSlot.WAIST] += quat_apply(
            quat[:, TrackerSlot.WAIST], np.asarray(old.waist_offset_m)
        )
    raw /= old.scale
    news = [new] * len(pos)
    q = orient_all(news, raw_q)
    return apply_all(news, raw, q), q


@dataclass
class WaistFilter:
    """One-pole low-pass on the waist orientation, by slerp toward each new sample.

    The paper filters the waist quaternion with a 6th-order Butterworth at a 100 Hz
    cutoff; at a 60 Hz tracker rate that cutoff lies above Nyquist (30 Hz) and would
    not filter at all, so posecast offers a plain, causal, configurable cutoff.
    """

    cutoff_hz: float
    fps: float = 60.0
    state: F64 | None = field(default=None)

    def __call__(self, quat: F64) -> F64:
        alpha = 1.0 - np.exp(-2.0 * np.pi * self.cutoff_hz / self.fps)
        q = quat_normalize(quat)
        self.state = q if self.state is None else quat_slerp(self.state, q, alpha)
        return self.state
