"""Training arrays (offline.train.data): a prepared split rebuilt clip by clip, in each
layout's view, augmented; windows that never straddle two clips; tracker sets composed
from their two views; and the inputs' normalisation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from posecast.offline.dataset.augment import Augmentation
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.dataset.store import load_split
from posecast.offline.train.data import (
    ALL_INERTIAL,
    ALL_POSITIONAL,
    Normalisation,
    TrainArrays,
    build_arrays,
    clip_from_split,
    compose_sites,
    load_train_val,
)
from posecast.tracking.layouts import Layout, spec
from posecast.tracking.sites import FEATURES_PER_SITE, NUM_SITES, Kind


def _arrays(starts: list[int], n_features: int = 2) -> TrainArrays:
    n = starts[-1]
    z = np.zeros
    return TrainArrays(
        np.arange(n * n_features, dtype=np.float32).reshape(n, n_features),
        z((n, 19, 3), np.float32), z((n, 18, 6), np.float32), z((n, 3, 3), np.float32),
        z((n, 2), np.float32), np.array(starts, np.int64),
    )  # fmt: skip


def test_windows_fit_inside_one_clip() -> None:
    arr = _arrays([0, 5, 7, 15])
    assert arr.n_frames == 15
    assert arr.window_starts(3).tolist() == [0, 1, 2, 7, 8, 9, 10, 11, 12]
    assert arr.window_starts(6).tolist() == [7, 8, 9]
    assert arr.window_starts(9).tolist() == [] and arr.window_starts(9).dtype == np.int64


def test_a_clip_rebuilt_from_its_split_gives_back_its_frames(prepared_dir: Path) -> None:
    split = load_split(prepared_dir, "train")
    clip = clip_from_split(split, 0)
    assert clip.name == split.clips[0]["name"] and clip.fps == split.fps
    again = derive_frames(clip)
    for key in ("positions", "tracker_pos", "features", "contacts"):
        np.testing.assert_allclose(again[key], split.clip(0)[key], atol=1e-4, err_msg=key)


def test_arrays_of_each_layout_and_the_augmented_variants(prepared_dir: Path) -> None:
    split = load_split(prepared_dir, "train")
    plain = build_arrays(split, Augmentation.none())
    np.testing.assert_array_equal(plain.clip_start, split.clip_start)
    np.testing.assert_allclose(plain.features, split.frames["features"], atol=1e-4)
    assert plain.features_imu is None and plain.root_mat.shape == (plain.n_frames, 3, 3)
    assert all(a.dtype == np.float32 and a.flags.c_contiguous
               for a in (plain.features, plain.local_pos, plain.rot6d, plain.contacts))  # fmt: skip
    doubled = build_arrays(split, Augmentation(mirror=True, speeds=(1.0, 2.0)), seed=1)
    assert len(doubled.clip_start) - 1 == 4 * split.n_clips  # mirrored, two speeds
    hmd3 = build_arrays(split, Augmentation.none(), layout=Layout.HMD3)
    assert hmd3.features.shape == (plain.n_frames, spec(Layout.HMD3).n_features)
    sites = build_arrays(split, Augmentation.none(), layout=Layout.SITES)
    assert sites.features.shape == (plain.n_frames, NUM_SITES * FEATURES_PER_SITE)
    assert sites.features_imu is not None and sites.features_imu.shape == sites.features.shape
    # the required sites are positional in both views, the optional ones differ
    req = slice(0, 3 * FEATURES_PER_SITE)
    np.testing.assert_array_equal(sites.features[:, req], sites.features_imu[:, req])
    assert not np.allclose(sites.features[:, req.stop :], sites.features_imu[:, req.stop :])


def test_sets_take_each_sites_columns_from_the_view_its_kind_names() -> None:
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(2, 3, NUM_SITES * FEATURES_PER_SITE))
    imu = rng.normal(size=pos.shape)
    kinds = np.stack([ALL_POSITIONAL, ALL_INERTIAL]).astype(np.int8)
    kinds[1, 9] = Kind.ABSENT
    out = compose_sites(pos, imu, kinds).reshape(2, 3, NUM_SITES, FEATURES_PER_SITE)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0], pos[0].reshape(3, NUM_SITES, -1), rtol=1e-6)
    np.testing.assert_allclose(out[1, :, :3], pos[1].reshape(3, NUM_SITES, -1)[:, :3], rtol=1e-6)
    np.testing.assert_allclose(out[1, :, 3:9], imu[1].reshape(3, NUM_SITES, -1)[:, 3:9], rtol=1e-6)
    assert not out[1, :, 9].any()


def test_normalisation_is_fit_floored_and_round_trips() -> None:
    arr = _arrays([0, 4, 10])
    arr.local_pos[:] = np.arange(10, dtype=np.float32)[:, None, None]
    norm = Normalisation.fit(arr)
    np.testing.assert_allclose(norm.feat_mean, arr.features.mean(0))
    np.testing.assert_allclose(norm.feat_std, arr.features.std(0), rtol=1e-6)
    assert norm.pose_mean.shape == norm.pose_std.shape == (57,)
    const = _arrays([0, 4])
    const.features[:] = 3.0
    assert np.all(Normalisation.fit(const).feat_std == np.float32(1e-3))  # the floor
    back = Normalisation.from_dict(norm.to_dict())
    for k in ("feat_mean", "feat_std", "pose_mean", "pose_std"):
        np.testing.assert_array_equal(getattr(back, k), getattr(norm, k))


def test_a_sets_normalisation_is_a_scale_only() -> None:
    """Absent sites read 0 and must stay 0 after normalisation: mean 0, and each column's
    root mean square over the view where it is present."""
    arr = _arrays([0, 6], n_features=3)
    imu = np.array(arr.features * -2.0)
    sets = TrainArrays(arr.features, arr.local_pos, arr.rot6d, arr.root_mat, arr.contacts,
                       arr.clip_start, imu)  # fmt: skip
    norm = Normalisation.fit(sets)
    assert not norm.feat_mean.any()
    want = np.sqrt(np.square(imu.astype(np.float64)).mean(0))
    np.testing.assert_allclose(norm.feat_std, np.maximum(want, 1e-3), rtol=1e-6)


def test_train_and_val_come_from_their_splits(prepared_dir: Path) -> None:
    manifest, train, val = load_train_val(prepared_dir, Augmentation(), seed=0)
    assert manifest["format"]
    assert len(train.clip_start) - 1 == 2 * load_split(prepared_dir, "train").n_clips
    np.testing.assert_array_equal(val.clip_start, load_split(prepared_dir, "val").clip_start)
