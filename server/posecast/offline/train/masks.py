"""Random tracker sets for training the one model of every set (``Layout.SITES``).

Each training window gets one set, fixed over the window (a player's set does not
change mid-session). A share of the windows (``table_share``) takes one of the sets the
evaluation table reports, uniformly; the rest are drawn site by site:

==============  ==========  ========  ========  =====================================
site            positional  inertial  absent
==============  ==========  ========  ========  =====================================
head, hands     1           0         0         required
waist           0.50        0.15      0.35
feet (pair)     0.35        0.30      0.35      each re-drawn alone with p = 0.1
knees (pair)    0.20        0.20      0.60      each re-drawn alone with p = 0.1
elbows (pair)   0.10        0.10      0.80      each re-drawn alone with p = 0.1
==============  ==========  ========  ========  =====================================

Inertial inputs are synthesised from the mocap (:func:`posecast.tracking.sites.site_tracks`:
the bone's world rotation, the site's central second difference) and get sensor noise
here, in m/s^2 before normalisation: white noise of ``acc_noise`` per axis and frame,
and a bias of ``acc_bias`` per axis held over the window.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.tracking.sites import FEATURES_PER_SITE, NUM_SITES, SITE_ROW, Kind, Site, TrackerSet

# The sets of the evaluation table (docs/evaluation.md), by short name.
TABLE_SETS: dict[str, str] = {
    "3p": "head,left_hand,right_hand",
    "4p": "head,left_hand,right_hand,waist",
    "6p": "head,left_hand,right_hand,waist,left_foot,right_foot",
    "8p": "head,left_hand,right_hand,waist,left_foot,right_foot,left_knee,right_knee",
    "3p+2i": "head,left_hand,right_hand,left_foot:imu,right_foot:imu",
    "3p+4i": "head,left_hand,right_hand,left_foot:imu,right_foot:imu,left_knee:imu,right_knee:imu",
}
TABLE_KINDS = np.stack([TrackerSet.parse(s).kinds() for s in TABLE_SETS.values()])

_P = (Kind.POSITIONAL, Kind.INERTIAL, Kind.ABSENT)
_SINGLE: dict[Site, tuple[float, float, float]] = {Site.WAIST: (0.50, 0.15, 0.35)}
_PAIRS: dict[tuple[Site, Site], tuple[float, float, float]] = {
    (Site.LEFT_FOOT, Site.RIGHT_FOOT): (0.35, 0.30, 0.35),
    (Site.LEFT_KNEE, Site.RIGHT_KNEE): (0.20, 0.20, 0.60),
    (Site.LEFT_ELBOW, Site.RIGHT_ELBOW): (0.10, 0.10, 0.80),
}
UNPAIRED = 0.1


def sample_kinds(rng: np.random.Generator, n: int, table_share: float = 0.25) -> NDArray[np.int8]:
    """``(n, 10)`` site kinds, one set per window."""
    out = np.zeros((n, NUM_SITES), np.int8)
    out[:, :3] = Kind.POSITIONAL
    kinds = np.array(_P, np.int8)
    for site, p in _SINGLE.items():
        out[:, SITE_ROW[site]] = rng.choice(kinds, n, p=p)
    for (left, right), p in _PAIRS.items():
        pair = rng.choice(kinds, n, p=p)
        for site in (left, right):
            alone = rng.random(n) < UNPAIRED
            out[:, SITE_ROW[site]] = np.where(alone, rng.choice(kinds, n, p=p), pair)
    table = rng.random(n) < table_share
    out[table] = TABLE_KINDS[rng.integers(0, len(TABLE_KINDS), int(table.sum()))]
    return out


def cycle_table_kinds(n: int) -> NDArray[np.int8]:
    """``(n, 10)``: the table's sets in turn (validation windows, reproducibly)."""
    return TABLE_KINDS[np.arange(n) % len(TABLE_KINDS)].astype(np.int8)


def add_inertial_noise(
    features: NDArray[np.float32],
    kinds: NDArray[np.integer],
    rng: np.random.Generator,
    acc_noise: float,
    acc_bias: float,
) -> None:
    """In place: sensor noise on the accelerations of the inertial sites of raw
    features ``(B, T, 170)`` with kinds ``(B, 10)``."""
    if acc_noise <= 0 and acc_bias <= 0:
        return
    B, T = features.shape[:2]
    f = features.reshape(B, T, NUM_SITES, FEATURES_PER_SITE)
    on = (np.asarray(kinds) == Kind.INERTIAL)[:, None, :, None]  # (B, 1, 10, 1)
    noise = rng.normal(0.0, acc_noise, (B, T, NUM_SITES, 3)) + rng.normal(
        0.0, acc_bias, (B, 1, NUM_SITES, 3)
    )
    f[..., FEATURES_PER_SITE - 3 :] += np.where(on, noise, 0.0).astype(np.float32)
