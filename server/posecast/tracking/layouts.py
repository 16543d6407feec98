"""Tracker layouts: which points a player sends, and what the model for them looks like.

=============  ==========================  ==========  ===========================
layout         trackers                    features    root (pelvis) pose from
=============  ==========================  ==========  ===========================
``hmd3+waist`` head, both hands, waist     24          the waist tracker
``hmd3``       head, both hands            36          the decoder (9 more outputs)
``sites``      any tracker set (3 to 10    170         a positional waist tracker
               sites, positional or                    if the set has one, else
               inertial; see                           the decoder
               :mod:`posecast.tracking.sites`)
=============  ==========================  ==========  ===========================

Each layout has its own *frame*: the yaw frame of one tracker (origin on the floor
under it, turned by its inverse heading) in which features and targets live. The
4-point model uses the waist's, the headset-only model the head's. A model's sidecar
names its layout; the engine builds one batch per layout. Players of every tracker set
share the ``sites`` model's batch: its features carry each site's presence.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast.geometry.rotations import quat2mat, quat_conj, r6d2mat
from posecast.tracking.features import (
    FEATURE_NAMES,
    FEATURE_NAMES_HMD3,
    NUM_FEATURES,
    NUM_FEATURES_HMD3,
    TrackerSlot,
    character_frame,
    hmd3_features,
    tracker_features,
)
from posecast.tracking.sites import (
    FEATURE_NAMES_SITES,
    NUM_FEATURES_SITES,
    NUM_SITES,
    TrackerSet,
    TrackerSetError,
    site_features,
)

F = NDArray[np.float64]

ROOT_OUTPUTS = 9  # 6D pelvis rotation + pelvis position, both in the head frame


class Layout(StrEnum):
    HMD3_WAIST = "hmd3+waist"
    HMD3 = "hmd3"
    SITES = "sites"  # the model of every tracker set; never a hello's layout itself


def _features_4(
    pos: ArrayLike, prev: ArrayLike, quat: ArrayLike, fps: float, kinds: ArrayLike | None
) -> F:
    return tracker_features(pos, prev, np.asarray(quat)[..., TrackerSlot.WAIST, :], fps)


def _features_3(
    pos: ArrayLike, prev: ArrayLike, quat: ArrayLike, fps: float, kinds: ArrayLike | None
) -> F:
    return hmd3_features(pos, prev, quat, fps)


def _features_sites(
    pos: ArrayLike, prev: ArrayLike, quat: ArrayLike, fps: float, kinds: ArrayLike | None
) -> F:
    if kinds is None:
        raise ValueError("the sites layout needs each player's site kinds")
    return site_features(pos, prev, quat, kinds, fps)


@dataclass(frozen=True)
class LayoutSpec:
    layout: Layout
    slots: tuple[TrackerSlot, ...]
    feature_names: tuple[str, ...]
    frame_slot: TrackerSlot  # the tracker whose yaw frame features and targets use
    root_outputs: int  # decoder outputs for the pelvis pose (0: the waist tracker gives it)
    decoder: str  # artifact name of the shipped decoder
    anomaly: str  # artifact name of the shipped anomaly autoencoder
    # (positions or, inertial sites, accelerations; previous; orientations; fps;
    # per-row site kinds, ``sites`` only) -> features
    features: Callable[[ArrayLike, ArrayLike, ArrayLike, float, ArrayLike | None], F]
    rows: int = 4  # tracker rows a frame has in the engine (sites: one per site)

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    @property
    def predicts_root(self) -> bool:
        return self.root_outputs > 0

    def clip_features(self, pos: ArrayLike, quat: ArrayLike, fps: float) -> F:
        """Features of a whole clip of trackers ``(F, 4, 3)`` / ``(F, 4, 4)``."""
        p = np.asarray(pos, dtype=np.float64)
        prev = np.concatenate([p[:1], p[:-1]], axis=0)
        return self.features(p, prev, quat, fps, None)


SPECS: dict[Layout, LayoutSpec] = {
    Layout.HMD3_WAIST: LayoutSpec(
        Layout.HMD3_WAIST,
        tuple(TrackerSlot),
        FEATURE_NAMES,
        TrackerSlot.WAIST,
        0,
        "cvae_decoder",
        "anomaly",
        _features_4,
    ),
    Layout.HMD3: LayoutSpec(
        Layout.HMD3,
        (TrackerSlot.HEAD, TrackerSlot.LEFT_HAND, TrackerSlot.RIGHT_HAND),
        FEATURE_NAMES_HMD3,
        TrackerSlot.HEAD,
        ROOT_OUTPUTS,
        "cvae_decoder_hmd3",
        "anomaly",
        _features_3,
    ),
    Layout.SITES: LayoutSpec(
        Layout.SITES,
        tuple(TrackerSlot),
        FEATURE_NAMES_SITES,
        TrackerSlot.HEAD,
        ROOT_OUTPUTS,
        "cvae_decoder_sites",
        "anomaly",
        _features_sites,
        NUM_SITES,
    ),
}
assert SPECS[Layout.HMD3_WAIST].n_features == NUM_FEATURES
assert SPECS[Layout.HMD3].n_features == NUM_FEATURES_HMD3
assert SPECS[Layout.SITES].n_features == NUM_FEATURES_SITES


def pelvis_from_head(root_out: ArrayLike, head_pos: ArrayLike, head_quat: ArrayLike) -> tuple[F, F]:
    """World pelvis rotations ``(R, 3, 3)`` and positions ``(R, 3)`` from the headset-only
    decoder's ``root`` outputs ``(R, 9)`` and the head trackers ``(R, 3)`` / ``(R, 4)``:
    the outputs live in the head's yaw frame (origin on the floor under the head)."""
    origin, inv_yaw = character_frame(head_pos, head_quat)
    yaw = quat2mat(quat_conj(inv_yaw))  # (R, 3, 3)
    out = np.asarray(root_out, dtype=np.float64)
    return yaw @ r6d2mat(out[:, :6]), origin + (yaw @ out[:, 6:9, None])[..., 0]


def spec(layout: str | Layout) -> LayoutSpec:
    """The spec of ``layout`` (raises ``ValueError`` for an unknown name)."""
    return SPECS[Layout(layout)]


PlayerLayout = Layout | TrackerSet  # what a player declares: a named layout or a set


def parse_layout(text: str) -> PlayerLayout:
    """A ``hello.layout`` string: a named layout (``hmd3+waist``, ``hmd3``) or a tracker
    set (:class:`~posecast.tracking.sites.TrackerSet`). Raises
    :class:`~posecast.tracking.sites.TrackerSetError` (a ``ValueError``) saying why not."""
    if text in (Layout.HMD3_WAIST, Layout.HMD3):
        return Layout(text)
    if text == Layout.SITES:
        raise TrackerSetError("'sites' names the model; list the tracker set's sites")
    return TrackerSet.parse(text)


def model_layout(layout: PlayerLayout) -> Layout:
    """The model (engine batch) that serves a player's layout."""
    return Layout.SITES if isinstance(layout, TrackerSet) else layout
