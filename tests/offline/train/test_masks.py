"""Random tracker sets for training the sites model (offline.train.masks): what is always
tracked, the table's sets in turn, and the inertial sites' sensor noise."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.train.masks import (
    TABLE_KINDS,
    TABLE_SETS,
    add_inertial_noise,
    cycle_table_kinds,
    sample_kinds,
)
from posecast.tracking.sites import FEATURES_PER_SITE, NUM_SITES, Kind, TrackerSet


def test_training_sets_always_track_head_and_hands_and_cover_every_kind() -> None:
    kinds = sample_kinds(np.random.default_rng(1), 4000)
    assert (kinds[:, :3] == Kind.POSITIONAL).all()
    for row in range(3, 10):
        seen = set(np.unique(kinds[:, row]).tolist())
        assert seen == {0, 1, 2}, row


def test_the_validation_windows_cycle_through_the_tables_sets() -> None:
    kinds = cycle_table_kinds(len(TABLE_SETS) * 2 + 1)
    assert kinds.dtype == np.int8 and kinds.shape == (len(TABLE_SETS) * 2 + 1, 10)
    for i, text in enumerate([*TABLE_SETS.values(), *TABLE_SETS.values(), "3p"]):
        want = TrackerSet.parse(TABLE_SETS.get(text, text)).kinds()
        np.testing.assert_array_equal(kinds[i], want)


def test_a_share_of_the_training_windows_takes_a_table_set() -> None:
    """``table_share`` of the windows take a table set; the rest are drawn site by site
    (where a table set, mostly ``3p``, also comes up by chance)."""
    table = {k.tobytes() for k in TABLE_KINDS}

    def rate(share: float) -> float:
        kinds = sample_kinds(np.random.default_rng(2), 4000, table_share=share)
        return float(np.mean([k.tobytes() in table for k in kinds]))

    assert rate(1.0) == 1.0
    by_chance = rate(0.0)
    assert 0.05 < by_chance < 0.5
    assert rate(0.5) == pytest.approx(0.5 + 0.5 * by_chance, abs=0.03)


def test_inertial_noise_lands_on_the_inertial_sites_accelerations_only() -> None:
    kinds = np.stack([TrackerSet.parse(TABLE_SETS["3p+2i"]).kinds()] * 2)  # feet inertial
    features = np.zeros((2, 50, NUM_SITES * FEATURES_PER_SITE), np.float32)
    add_inertial_noise(features, kinds, np.random.default_rng(0), acc_noise=0.5, acc_bias=0.2)
    f = features.reshape(2, 50, NUM_SITES, FEATURES_PER_SITE)
    inertial = kinds[0] == Kind.INERTIAL
    assert inertial.sum() == 2
    assert np.all(f[:, :, inertial, FEATURES_PER_SITE - 3 :] != 0)
    assert not f[:, :, ~inertial].any() and not f[:, :, :, : FEATURES_PER_SITE - 3].any()
    acc = f[:, :, inertial, FEATURES_PER_SITE - 3 :]
    assert 0.4 < acc.std() < 0.7  # white noise 0.5 and a bias 0.2 per window: sqrt(0.29)
    before = features.copy()
    add_inertial_noise(features, kinds, np.random.default_rng(0), acc_noise=0.0, acc_bias=0.0)
    np.testing.assert_array_equal(features, before)
