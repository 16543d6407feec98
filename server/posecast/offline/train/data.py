"""Training arrays: a prepared split, augmented, in the networks' view.

Every array is per frame; clips are concatenated and ``clip_start`` marks them, so
windows never straddle two clips.

==============  ============  =======================================================
field           shape         meaning
==============  ============  =======================================================
features        (N, F)        tracker features of the (possibly rescaled) body (F: 24
                              for ``hmd3+waist``, 36 for ``hmd3``)
local_pos       (N, 19, 3)    canonical-body joint positions in the layout's frame
                              (the waist's or the head's yaw frame), metres
rot6d           (N, 18, 6)    target local rotations
root_mat        (N, 3, 3)     pelvis rotation in that frame
contacts        (N, 2)        foot contact labels
features_imu    (N, F)        ``sites`` only: the features with every optional site
                              inertial (``features`` has every site positional); a
                              training batch takes each site's columns from one, the
                              other or neither, per window (:func:`compose_sites`)
==============  ============  =======================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.rotations import mat2quat, quat2mat, quat_mul, r6d2mat
from posecast.offline.dataset.augment import Augmentation, change_speed, mirror, scale_bones
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.dataset.store import SplitData, load_split, read_manifest
from posecast.offline.motion.clip import CanonicalClip
from posecast.tracking.features import character_frame, to_character_frame
from posecast.tracking.layouts import Layout, LayoutSpec, spec
from posecast.tracking.sites import (
    FEATURES_PER_SITE,
    NUM_SITES,
    REQUIRED,
    Kind,
    clip_site_features,
    site_tracks,
)

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class TrainArrays:
    features: F32
    local_pos: F32
    rot6d: F32
    root_mat: F32
    contacts: F32
    clip_start: NDArray[np.int64]
    features_imu: F32 | None = None

    @property
    def n_frames(self) -> int:
        return int(self.features.shape[0])

    def window_starts(self, length: int) -> NDArray[np.int64]:
        """Every frame index where a window of ``length`` fits inside one clip."""
        out = [
            np.arange(a, b - length + 1)
            for a, b in zip(self.clip_start[:-1], self.clip_start[1:], strict=True)
            if b - a >= length
        ]
        return np.concatenate(out).astype(np.int64) if out else np.zeros(0, np.int64)


def clip_from_split(split: SplitData, i: int) -> CanonicalClip:
    """Rebuild clip ``i`` of a prepared split as a :class:`CanonicalClip`."""
    fr = split.clip(i)
    rot = mat2quat(r6d2mat(fr["rot6d"].astype(np.float64)))  # (F, 18, 4)
    local = np.concatenate([fr["root_quat"][:, None].astype(np.float64), rot], axis=1)
    meta = split.clips[i]
    return CanonicalClip(
        name=str(meta["name"]),
        subject=str(meta["subject"]),
        fps=split.fps,
        local_quat=local,
        root_pos=fr["root_pos"].astype(np.float64),
    )


def _views(
    clip: CanonicalClip, body: CanonicalClip, ls: LayoutSpec
) -> dict[str, NDArray[np.floating]]:
    target = derive_frames(clip)
    sensed = derive_frames(body) if body is not clip else target
    root_q = target["root_quat"].astype(np.float64)
    frame_pos = target["tracker_pos"][:, ls.frame_slot].astype(np.float64)
    frame_quat = target["tracker_quat"][:, ls.frame_slot].astype(np.float64)
    _, inv_yaw = character_frame(frame_pos, frame_quat)
    features: NDArray[np.floating]
    extra: dict[str, NDArray[np.floating]] = {}
    if ls.layout is Layout.HMD3_WAIST:
        features = sensed["features"]  # derived once, at prepare time
    elif ls.layout is Layout.SITES:
        pos, quat, acc = site_tracks(*body.fk(), clip.fps)
        features = clip_site_features(pos, quat, acc, ALL_POSITIONAL, clip.fps)
        extra["features_imu"] = clip_site_features(pos, quat, acc, ALL_INERTIAL, clip.fps)
    else:
        features = ls.clip_features(sensed["tracker_pos"], sensed["tracker_quat"], clip.fps)
    return {
        **extra,
        "features": features,
        "local_pos": to_character_frame(target["positions"], frame_pos, frame_quat),
        "rot6d": target["rot6d"],
        "root_mat": quat2mat(quat_mul(inv_yaw, root_q)),
        "contacts": target["contacts"],
    }


def build_arrays(
    split: SplitData, aug: Augmentation, seed: int = 0, layout: str = Layout.HMD3_WAIST
) -> TrainArrays:
    """All clips of ``split``, each in every augmented variant ``aug`` asks for, in the
    view of ``layout``'s model."""
    ls = spec(layout)
    rng = np.random.default_rng(seed)
    parts: list[dict[str, NDArray[np.floating]]] = []
    for i in range(split.n_clips):
        base = clip_from_split(split, i)
        variants = [base, mirror(base)] if aug.mirror else [base]
        for v in variants:
            for speed in aug.speeds:
                clip = change_speed(v, speed)
                if clip.n_frames < 2:
                    continue
                parts.append(_views(clip, scale_bones(clip, rng, aug), ls))
    lengths = [len(p["features"]) for p in parts]
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)

    def cat(key: str) -> F32:
        return np.ascontiguousarray(np.concatenate([p[key] for p in parts]), dtype=np.float32)

    return TrainArrays(
        features=cat("features"),
        local_pos=cat("local_pos"),
        rot6d=cat("rot6d"),
        root_mat=cat("root_mat"),
        contacts=cat("contacts"),
        clip_start=starts,
        features_imu=cat("features_imu") if parts and "features_imu" in parts[0] else None,
    )


# Every optional site positional, or inertial (the head and hands always positional).
ALL_POSITIONAL = np.full(NUM_SITES, Kind.POSITIONAL, np.int8)
ALL_INERTIAL = np.where(np.arange(NUM_SITES) < len(REQUIRED), Kind.POSITIONAL, Kind.INERTIAL)


def compose_sites(
    positional: NDArray[np.floating], inertial: NDArray[np.floating], kinds: NDArray[np.integer]
) -> F32:
    """Features of tracker sets from the two full views: ``positional`` and
    ``inertial`` ``(B, T, 170)``, ``kinds (B, 10)`` per window -> ``(B, T, 170)``, each
    site's 17 columns from the view its kind names, zeros where it is absent."""
    B, T = positional.shape[:2]
    p = positional.reshape(B, T, NUM_SITES, FEATURES_PER_SITE)
    i = inertial.reshape(B, T, NUM_SITES, FEATURES_PER_SITE)
    k = np.asarray(kinds)[:, None, :, None]
    out = np.where(k == Kind.POSITIONAL, p, np.where(k == Kind.INERTIAL, i, 0.0))
    return np.ascontiguousarray(out.reshape(B, T, -1), dtype=np.float32)


@dataclass(frozen=True)
class Normalisation:
    """Mean and standard deviation of the network inputs, from the training arrays."""

    feat_mean: F32
    feat_std: F32
    pose_mean: F32
    pose_std: F32

    @classmethod
    def fit(cls, arr: TrainArrays) -> Normalisation:
        pos = arr.local_pos.reshape(len(arr.local_pos), -1)
        if arr.features_imu is not None:
            # Tracker sets: a scale only (mean 0, the root mean square of each column
            # in the view where it is present), so that an absent site's zeros stay 0.
            msq = np.maximum(
                np.square(arr.features, dtype=np.float64).mean(0),
                np.square(arr.features_imu, dtype=np.float64).mean(0),
            )
            feat_mean = np.zeros(arr.features.shape[1], np.float32)
            feat_std = np.maximum(np.sqrt(msq), 1e-3).astype(np.float32)
        else:
            feat_mean = arr.features.mean(0).astype(np.float32)
            feat_std = np.maximum(arr.features.std(0), 1e-3).astype(np.float32)
        # A floor on the std keeps constant inputs (the waist's own X/Z) finite.
        return cls(
            feat_mean=feat_mean,
            feat_std=feat_std,
            pose_mean=pos.mean(0).astype(np.float32),
            pose_std=np.maximum(pos.std(0), 1e-3).astype(np.float32),
        )

    def to_dict(self) -> dict[str, list[float]]:
        return {k: [float(v) for v in getattr(self, k)] for k in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, d: dict[str, list[float]]) -> Normalisation:
        return cls(**{k: np.asarray(d[k], dtype=np.float32) for k in cls.__dataclass_fields__})


def load_train_val(
    data_dir: str | Path, aug: Augmentation, seed: int, layout: str = Layout.HMD3_WAIST
) -> tuple[dict[str, object], TrainArrays, TrainArrays]:
    """The prepared dataset's manifest, its augmented train split and its plain val split."""
    manifest = read_manifest(data_dir)
    train = build_arrays(load_split(data_dir, "train"), aug, seed=seed, layout=layout)
    val = build_arrays(load_split(data_dir, "val"), Augmentation.none(), seed, layout)
    return manifest, train, val
