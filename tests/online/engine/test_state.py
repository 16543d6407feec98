"""The engine's per-player state by name (posecast.online.engine.state)."""

from __future__ import annotations

import numpy as np

from posecast.body.pipeline import ShownState
from posecast.online.engine.state import IK_SHAPES, RESCALED, SHOWN, state_specs
from posecast.tracking.layouts import Layout, spec


def test_the_shown_names_match_shown_state_arrays_in_shape_and_order() -> None:
    """SHOWN[i] holds ShownState.arrays()[i] of one player: same per-player shape."""
    specs = state_specs(4, 8, 8, 16, spec(Layout.HMD3_WAIST), 3)
    zeros = ShownState.zeros(1).arrays()
    assert len(SHOWN) == len(zeros)
    for name, array in zip(SHOWN, zeros, strict=True):
        assert specs[name][0] == array.shape[1:], name


def test_every_rescaled_and_pool_ik_name_is_a_slot_array() -> None:
    specs = state_specs(5, 8, 8, 16, spec(Layout.HMD3), 4)
    assert set(RESCALED) <= set(specs)
    for name, shape in IK_SHAPES.items():
        assert specs[f"ik_{name}"][0] == (5, *shape)
    assert specs["ring_h"] == ((5, 16), np.float32, 4)  # ring arrays carry their length
