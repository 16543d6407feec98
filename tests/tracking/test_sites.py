"""Tracker sets: parsing, model rows and the one model's features."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.train.masks import TABLE_SETS
from posecast.tracking.layouts import Layout, model_layout, parse_layout
from posecast.tracking.sites import (
    FEATURES_PER_SITE,
    NUM_FEATURES_SITES,
    Kind,
    Site,
    TrackerSet,
    TrackerSetError,
    site_features,
)


def test_a_set_parses_in_wire_order_and_names_itself_back() -> None:
    text = "head,left_hand,right_hand,left_foot:imu,right_foot:imu,waist"
    ts = TrackerSet.parse(text)
    assert ts.name == text and len(ts) == 6
    assert ts.kind(Site.LEFT_FOOT) is Kind.INERTIAL and ts.kind(Site.WAIST) is Kind.POSITIONAL
    assert ts.kind(Site.LEFT_KNEE) is Kind.ABSENT and ts.tracks_waist
    assert ts.rows.tolist() == [0, 1, 2, 4, 5, 3]
    rows = ts.to_rows(np.arange(18.0).reshape(6, 3), [0.0, 0.0, 0.0])
    assert rows[3].tolist() == [15.0, 16.0, 17.0] and not rows[6:].any()


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("head,left_hand,right_hand,tail", "unknown site 'tail'"),
        ("head,left_hand,right_hand,head", "listed twice"),
        ("left_hand,right_hand,waist", "needs a 'head'"),
        ("head:imu,left_hand,right_hand", "positional 'head'"),
        ("head,left_hand", "'right_hand'"),
        ("", "non-empty"),
        ("head,,left_hand", "unknown site ''"),
    ],
)
def test_bad_sets_say_why(text: str, why: str) -> None:
    with pytest.raises(TrackerSetError, match=why):
        TrackerSet.parse(text)


def test_named_layouts_keep_their_models_and_sets_go_to_the_sites_model() -> None:
    assert parse_layout("hmd3") is Layout.HMD3
    assert model_layout(parse_layout("hmd3+waist")) is Layout.HMD3_WAIST
    assert model_layout(parse_layout(TABLE_SETS["6p"])) is Layout.SITES
    with pytest.raises(TrackerSetError):
        parse_layout("sites")


def test_absent_sites_read_zero_and_present_ones_carry_their_kind() -> None:
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(10, 3)) + np.array([0.0, 1.0, 0.0])
    q = rng.normal(size=(10, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    kinds = TrackerSet.parse(TABLE_SETS["3p+2i"]).kinds()
    f = site_features(pos, pos - 0.01, q, kinds, 60.0).reshape(10, FEATURES_PER_SITE)
    assert f.shape == (10, 17) and NUM_FEATURES_SITES == 170
    assert not f[[3, 6, 7, 8, 9]].any()  # waist, knees, elbows absent
    foot = f[4]
    assert foot[:2].tolist() == [0.0, 1.0] and not foot[2:8].any()  # no position, velocity
    assert np.isclose(np.linalg.norm(foot[14:]), np.linalg.norm(pos[4]))  # a turned accel
    hand = f[1]
    assert hand[:2].tolist() == [1.0, 0.0]
    assert np.isclose(np.linalg.norm(hand[5:8]), 0.6 * np.sqrt(3))  # 0.01 m a frame per axis
    assert not hand[14:].any()
