"""Tracker sets: any of ten body sites, each positional or inertial, for one model.

A *tracker set* lists the body sites a player tracks and what each tracker reports:

* **positional** (a headset, a controller, a lighthouse tracker): world position and
  orientation, ``[px, py, pz, qx, qy, qz, qw]`` on the wire;
* **inertial** (an IMU): world orientation and the world-frame linear acceleration with
  gravity removed, m/s^2, ``[ax, ay, az, qx, qy, qz, qw]`` on the wire.

Its name, which ``hello.layout`` carries, is the comma-separated list of its sites in
wire order, an inertial one suffixed ``:imu``, for example
``head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu``. Every set has the
head and both hands, positional (the upper-body pass puts them on their trackers);
the other seven sites are optional.

=========  ==============  ====================================================
model row  site            joint it sits on (position; orientation of)
=========  ==============  ====================================================
0          ``head``        ``HEAD``
1          ``left_hand``   ``LEFT_HAND``
2          ``right_hand``  ``RIGHT_HAND``
3          ``waist``       ``PELVIS``
4, 5       ``*_foot``      ``*_FOOT`` (the ankle; the foot's rotation)
6, 7       ``*_knee``      ``*_SHIN`` (the knee; the shin's rotation: strapped below it)
8, 9       ``*_elbow``     ``*_FOREARM`` (the elbow; the forearm's rotation)
=========  ==============  ====================================================

The first four rows are the slot order of the 4-point wire (``TrackerSlot``), so the
calibration and the upper-body pass read a set's head, hands and waist where they read
a 4-point frame's.

Features of the one model (``Layout.SITES``): everything in the head's yaw frame (as
the headset-only model's), per site in model row order 17 values::

    [positional, inertial,  px py pz,  vx vy vz,  r0..r5,  ax ay az]

the two presence flags (both 0: absent), position and velocity (m/s) of a positional
site, the orientation as 6D of any present site, and the acceleration (m/s^2) of an
inertial one. Everything a site does not report is 0, so an absent site reads as
zeros whatever the normalisation (the model's is a scale only).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast.geometry.rotations import mat2quat, quat2r6d, quat_apply, quat_mul
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot, character_frame

F = NDArray[np.float64]


class Site(StrEnum):
    HEAD = "head"
    LEFT_HAND = "left_hand"
    RIGHT_HAND = "right_hand"
    WAIST = "waist"
    LEFT_FOOT = "left_foot"
    RIGHT_FOOT = "right_foot"
    LEFT_KNEE = "left_knee"
    RIGHT_KNEE = "right_knee"
    LEFT_ELBOW = "left_elbow"
    RIGHT_ELBOW = "right_elbow"


class Kind(IntEnum):
    ABSENT = 0
    POSITIONAL = 1
    INERTIAL = 2


SITES: tuple[Site, ...] = tuple(Site)
NUM_SITES = len(SITES)  # 10
SITE_ROW: dict[Site, int] = {s: i for i, s in enumerate(SITES)}
HEAD_ROW = SITE_ROW[Site.HEAD]
SITE_JOINT: dict[Site, Joint] = {
    Site.HEAD: Joint.HEAD,
    Site.LEFT_HAND: Joint.LEFT_HAND,
    Site.RIGHT_HAND: Joint.RIGHT_HAND,
    Site.WAIST: Joint.PELVIS,
    Site.LEFT_FOOT: Joint.LEFT_FOOT,
    Site.RIGHT_FOOT: Joint.RIGHT_FOOT,
    Site.LEFT_KNEE: Joint.LEFT_SHIN,
    Site.RIGHT_KNEE: Joint.RIGHT_SHIN,
    Site.LEFT_ELBOW: Joint.LEFT_FOREARM,
    Site.RIGHT_ELBOW: Joint.RIGHT_FOREARM,
}
SITE_JOINT_INDEX: tuple[int, ...] = tuple(int(SITE_JOINT[s]) for s in SITES)
REQUIRED: tuple[Site, ...] = (Site.HEAD, Site.LEFT_HAND, Site.RIGHT_HAND)
assert all(SITE_ROW[s] == int(TrackerSlot[s.name]) for s in (*REQUIRED, Site.WAIST))

INERTIAL_SUFFIX = ":imu"
# Sensor noise on synthetic IMU accelerations (m/s^2, per axis), in training and in
# evaluation: white noise per frame, and a bias held over a window or clip.
IMU_ACC_NOISE = 0.5
IMU_ACC_BIAS = 0.2
FEATURES_PER_SITE = 17
NUM_FEATURES_SITES = NUM_SITES * FEATURES_PER_SITE  # 170
FEATURE_NAMES_SITES: tuple[str, ...] = tuple(
    f"{s.value}.{n}"
    for s in SITES
    for n in (
        "positional",
        "inertial",
        *(f"{k}{a}" for k in ("p", "v") for a in "xyz"),
        *(f"r{i}" for i in range(6)),
        *(f"a{a}" for a in "xyz"),
    )
)
# Column offsets inside one site's 17 values.
_FLAG_P, _FLAG_I, _POS, _VEL, _ROT, _ACC = 0, 1, 2, 5, 8, 14


class TrackerSetError(ValueError):
    """A layout string that names no valid tracker set (the reason is the message)."""


@dataclass(frozen=True)
class TrackerSet:
    """An ordered list of ``(site, kind)``: the wire order of a player's trackers."""

    entries: tuple[tuple[Site, Kind], ...]

    @classmethod
    def parse(cls, text: str) -> TrackerSet:
        """The set a layout string names; :class:`TrackerSetError` says why not."""
        if not isinstance(text, str) or not text:
            raise TrackerSetError("a tracker set is a non-empty string")
        entries: list[tuple[Site, Kind]] = []
        for token in text.split(","):
            name, kind = token, Kind.POSITIONAL
            if token.endswith(INERTIAL_SUFFIX):
                name, kind = token[: -len(INERTIAL_SUFFIX)], Kind.INERTIAL
            try:
                site = Site(name)
            except ValueError:
                raise TrackerSetError(f"unknown site {name!r}") from None
            if any(site is s for s, _ in entries):
                raise TrackerSetError(f"site {site.value!r} listed twice")
            entries.append((site, kind))
        out = cls(tuple(entries))
        for site in REQUIRED:
            if out.kind(site) is not Kind.POSITIONAL:
                missing = "positional " if out.kind(site) is Kind.INERTIAL else ""
                raise TrackerSetError(f"a tracker set needs a {missing}{site.value!r} tracker")
        return out

    @property
    def name(self) -> str:
        return ",".join(
            s.value + (INERTIAL_SUFFIX if k is Kind.INERTIAL else "") for s, k in self.entries
        )

    def __str__(self) -> str:
        return self.name

    def __len__(self) -> int:
        return len(self.entries)

    def kind(self, site: Site) -> Kind:
        for s, k in self.entries:
            if s is site:
                return k
        return Kind.ABSENT

    def kinds(self) -> NDArray[np.int8]:
        """``(10,)`` :class:`Kind` per model row."""
        out = np.zeros(NUM_SITES, np.int8)
        for s, k in self.entries:
            out[SITE_ROW[s]] = k
        return out

    @property
    def rows(self) -> NDArray[np.intp]:
        """The model row of each wire entry, ``(len(self),)``."""
        return np.array([SITE_ROW[s] for s, _ in self.entries], np.intp)

    def to_rows(self, values: ArrayLike, fill: ArrayLike) -> F:
        """Wire-order values ``(len(self), W)`` into model rows ``(10, W)``; absent rows
        take ``fill`` ``(W,)``."""
        v = np.asarray(values, dtype=np.float64)
        out = np.empty((NUM_SITES, v.shape[-1]))
        out[:] = np.asarray(fill, dtype=np.float64)
        out[self.rows] = v
        return out

    @property
    def tracks_waist(self) -> bool:
        """The waist is tracked with its position: the pelvis pose comes from it."""
        return self.kind(Site.WAIST) is Kind.POSITIONAL


def site_features(
    values: ArrayLike, prev: ArrayLike, quat: ArrayLike, kinds: ArrayLike, fps: float
) -> F:
    """The one model's input, for one or many frames.

    Args:
        values: ``(..., 10, 3)`` per model row, a positional site's position (metres)
            or an inertial site's world acceleration (m/s^2); absent rows are ignored.
        prev: ``(..., 10, 3)`` the previous frame's ``values`` (velocities of positional
            sites; pass ``values`` for a first frame).
        quat: ``(..., 10, 4)`` world orientations, xyzw (the head's must be valid).
        kinds: ``(..., 10)`` :class:`Kind` per row (broadcasts against the frames).
        fps: frame rate the velocities are measured at.

    Returns:
        ``(..., 170)`` in :data:`FEATURE_NAMES_SITES` order.
    """
    v = np.asarray(values, dtype=np.float64)
    pv = np.asarray(prev, dtype=np.float64)
    q = np.asarray(quat, dtype=np.float64)
    k = np.broadcast_to(np.asarray(kinds), v.shape[:-1])
    origin, inv_yaw = character_frame(v[..., HEAD_ROW, :], q[..., HEAD_ROW, :])
    iy = inv_yaw[..., None, :]
    is_p = (k == Kind.POSITIONAL)[..., None]
    is_i = (k == Kind.INERTIAL)[..., None]
    out = np.zeros((*v.shape[:-1], FEATURES_PER_SITE))
    out[..., _FLAG_P] = is_p[..., 0]
    out[..., _FLAG_I] = is_i[..., 0]
    out[..., _POS:_VEL] = np.where(is_p, quat_apply(iy, v - origin[..., None, :]), 0.0)
    out[..., _VEL:_ROT] = np.where(is_p, quat_apply(iy, (v - pv) * fps), 0.0)
    out[..., _ROT:_ACC] = np.where(is_p | is_i, quat2r6d(quat_mul(iy, q)), 0.0)
    out[..., _ACC:] = np.where(is_i, quat_apply(iy, v), 0.0)
    return out.reshape(*v.shape[:-2], NUM_FEATURES_SITES)


def site_tracks(world_mat: ArrayLike, world_pos: ArrayLike, fps: float) -> tuple[F, F, F]:
    """Synthetic trackers on every site of a posed clip: positions ``(F, 10, 3)``,
    orientations ``(F, 10, 4)`` and world accelerations ``(F, 10, 3)`` (m/s^2, the
    central second difference of the site's position; the first and last frames
    repeat their neighbours'), from world rotations ``(F, 19, 3, 3)`` and positions
    ``(F, 19, 3)``."""
    idx = list(SITE_JOINT_INDEX)
    pos = np.asarray(world_pos, dtype=np.float64)[:, idx]
    quat = mat2quat(np.asarray(world_mat, dtype=np.float64)[:, idx])
    acc = np.zeros_like(pos)
    if len(pos) >= 3:
        acc[1:-1] = (pos[2:] - 2.0 * pos[1:-1] + pos[:-2]) * fps * fps
        acc[0], acc[-1] = acc[1], acc[-2]
    return pos, quat, acc


def clip_site_features(
    pos: ArrayLike, quat: ArrayLike, acc: ArrayLike, kinds: ArrayLike, fps: float
) -> F:
    """:func:`site_features` of a whole clip of synthetic trackers ``(F, 10, ...)``."""
    p = np.asarray(pos, dtype=np.float64)
    k = np.asarray(kinds)
    values = np.where((k == Kind.INERTIAL)[..., None], np.asarray(acc, dtype=np.float64), p)
    prev = np.concatenate([values[:1], values[:-1]], axis=0)
    return site_features(values, prev, quat, k, fps)


def imu_noise(
    rng: np.random.Generator, frames: int, noise: float = IMU_ACC_NOISE, bias: float = IMU_ACC_BIAS
) -> F:
    """``(frames, 10, 3)`` sensor noise for a clip's synthetic accelerations: white
    noise of ``noise`` per axis and frame plus a bias of ``bias`` per axis held over
    the clip (m/s^2), on every row (only inertial rows read it)."""
    return rng.normal(0.0, noise, (frames, NUM_SITES, 3)) + rng.normal(0.0, bias, (1, NUM_SITES, 3))
