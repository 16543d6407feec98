"""The shown pose's pipeline (:func:`posecast.body.pipeline.show`): a batch shows what each
player alone would, its passes in numpy are what every backend's are, and with every
switch off it is the network's pose with its display contact IK."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from posecast.body.passes import NumpyPasses, Passes
from posecast.body.pipeline import Decoded, Shown, ShownState, show
from posecast.geometry.rotations import quat2mat
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.config import EngineConfig
from posecast.online.inference.auto import load_backend
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot
from tests.online.engine.conftest import available_backends

FRAMES = 40
LOWERED_M = 0.06  # the walks sink into the floor: the floor pass and the clearance lift


@cache
def _walks(players: int) -> tuple[np.ndarray, ...]:
    """``players`` ground-truth walks as decoded samples, ``(P, T, ...)``: rotations,
    contacts, the waist's pelvis, trackers (lowered by :data:`LOWERED_M`)."""
    w = [derive_frames(walk_clip(FRAMES / 60.0, 60.0, seed=s)) for s in range(players)]
    down = np.array([0.0, LOWERED_M, 0.0])
    rot = np.stack([f["rot6d"].reshape(FRAMES, 108) for f in w]).astype(np.float32)
    con = np.stack([f["contacts"] for f in w]).astype(np.float32)
    tp = np.stack([f["tracker_pos"] for f in w]).astype(np.float64) - down
    tq = np.stack([f["tracker_quat"] for f in w]).astype(np.float64)
    root_mat = quat2mat(tq[:, :, TrackerSlot.WAIST]).astype(np.float32)
    return rot, con, root_mat, tp[:, :, TrackerSlot.WAIST].astype(np.float32), tp, tq


def _stream(
    rows: list[int], passes: Passes, free: bool, players: int = 3, **switches: object
) -> list[Shown]:
    """``show`` frame by frame on the walks ``rows`` as one batch (the pelvis smoothed with
    its neighbours, ``free``: as the decoder's guess)."""
    cfg = EngineConfig(**switches)  # type: ignore[arg-type]
    rot, con, root_mat, root_pos, tp, tq = (a[rows] for a in _walks(players))
    state = ShownState.zeros(len(rows))
    out = []
    for t in range(FRAMES):
        near = [max(t - 1, 0), min(t + 1, FRAMES - 1)]
        batch = Decoded(
            rot[:, t],
            con[:, t],
            root_mat[:, t],
            root_pos[:, t],
            tp[:, t],
            tq[:, t],
            first=np.full(len(rows), t == 0),
            neighbours=(root_mat[:, near].swapaxes(0, 1), root_pos[:, near].swapaxes(0, 1)),
            free=np.ones(len(rows), np.bool_) if free else None,
        )
        out.append(show(batch, state, cfg, passes))
    return out


@pytest.mark.parametrize("free", [False, True])
def test_a_batch_shows_what_each_player_alone_shows(free: bool) -> None:
    """Three walkers in one batch, frame by frame, against each one alone: the same
    poses (each carries its own contact locks, toe speeds and reach)."""
    together = _stream([0, 1, 2], NumpyPasses(), free)
    for i in range(3):
        alone = _stream([i], NumpyPasses(), free)
        for a, b in zip(together, alone, strict=True):
            np.testing.assert_allclose(a.positions[i], b.positions[0], atol=1e-6)
            np.testing.assert_allclose(a.rotations[i], b.rotations[0], atol=1e-6)
            assert a.reach_limited[i] == b.reach_limited[0]


@pytest.mark.parametrize("name", [b for b in available_backends() if b == "native"])
def test_every_backends_passes_show_what_the_numpy_reference_shows(name: str) -> None:
    """The backend chosen by name runs the heaviest passes (``native``: in C; ``onnx``
    and ``torch`` run the reference itself); the streamed poses are the numpy
    reference's to float32's rounding: positions within 0.1 mm (measured 2e-5 m),
    rotation matrices within 1e-3 (measured 1.1e-4, a thigh's twist near a straight
    knee, where the hinge's fade is steep)."""
    pool = load_backend(name, "hmd3+waist", threads=1).pool
    for free in (False, True):
        ref = _stream([0, 1, 2], NumpyPasses(), free)
        got = _stream([0, 1, 2], pool, free)
        for a, b in zip(got, ref, strict=True):
            np.testing.assert_allclose(a.positions, b.positions, atol=1e-4)
            np.testing.assert_allclose(quat2mat(a.rotations), quat2mat(b.rotations), atol=1e-3)
            np.testing.assert_array_equal(a.reach_limited, b.reach_limited)


def test_with_every_switch_off_the_pose_is_the_networks_with_its_display_ik() -> None:
    """No pass but the FK and the display contact IK (``Passes.emit``): what is left
    when every switch is off, and the state's toes and reach stay as they were."""
    off = {
        k: False
        for k in (
            "pelvis_smoothing", "upper_body_ik", "floor_ik", "knee_hinge", "elbow_hinge",
            "legs_apart",
        )
    }  # fmt: skip
    shown = _stream([0, 1], NumpyPasses(), True, **off)
    rot, con, root_mat, root_pos, _, _ = (a[[0, 1]] for a in _walks(3))
    passes, ik = NumpyPasses(), ShownState.zeros(2).ik
    for t, s in enumerate(shown):
        wp, quats = passes.emit(rot[:, t], con[:, t], root_mat[:, t], root_pos[:, t], ik)
        np.testing.assert_array_equal(s.positions, wp)
        np.testing.assert_array_equal(s.rotations, quats)
        assert not s.reach_limited.any()


def test_the_passes_change_the_pose_where_they_should() -> None:
    """On the lowered walks the default pipeline lifts the feet onto the floor and puts
    the head on the headset wherever the spine reaches it (a 4-point user standing
    straight is at the chain's full extent; those poses say so, ``reach_limited``):
    the floor pass, the clearance and the upper-body pass all ran."""
    shown = _stream([0, 1, 2], NumpyPasses(), False)
    _, _, _, _, tp, _ = _walks(3)
    pos = np.stack([s.positions for s in shown], axis=1)  # (P, T, 19, 3)
    limited = np.stack([s.reach_limited for s in shown], axis=1)  # (P, T)
    assert pos[..., 1].min() > -1e-3  # no joint under the floor
    miss = np.linalg.norm(pos[:, :, Joint.HEAD] - tp[:, :, TrackerSlot.HEAD], axis=-1)
    assert np.all(miss[~limited] < 1e-3)
    assert limited.mean() < 0.2
