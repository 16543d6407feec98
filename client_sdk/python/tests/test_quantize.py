"""Pose quantisation (``quantize.py``): int16 millimetres from the exact root and
snorm16 quaternions, within the spec's error bounds, refusing what int16 cannot hold."""

from __future__ import annotations

import numpy as np
import pytest

from posecast_client.codec import decode, encode
from posecast_client.errors import (
    NotNormalisedError,
    OutOfRangeError,
)
from posecast_client.protocol import (
    Pose,
)
from posecast_client.quantize import (
    POS_BYTES,
    ROT_BYTES,
    mm2pos,
    pos2mm,
    quat2snorm,
    snorm2quat,
)
from posecast_client.rotations import quat_normalize
from posecast_client.skeleton import reference_offsets


def _unit_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    return quat_normalize(rng.normal(size=(n, 4)))


def test_pose_quantisation_error_is_within_the_spec(rng: np.random.Generator) -> None:
    positions = rng.uniform(-1, 1, (19, 3)) + np.array([100.0, 0.0, -300.0])
    rotations = _unit_quats(rng, 19)
    out = decode(encode(Pose("p-1", 9, 20.5, positions, rotations)))
    assert isinstance(out, Pose) and out.rotations is not None
    assert out.positions[0].tolist() == positions[0].tolist()  # the root is exact
    assert np.abs(out.positions - positions).max() <= 0.0005 + 1e-9  # 0.5 mm per axis
    assert np.abs(out.rotations - rotations).max() <= 0.5 / 32767 + 1e-12
    assert len(encode(Pose("p-17", 9, 20.5, positions))) == 189  # the spec's size example


def test_pose_encoder_refuses_what_int16_cannot_hold() -> None:
    positions = np.zeros((19, 3))
    positions[5, 0] = 40.0  # 40 m from the pelvis
    with pytest.raises(OutOfRangeError):
        encode(Pose("p", 1, 1.0, positions))
    with pytest.raises(NotNormalisedError):
        encode(Pose("p", 1, 1.0, np.zeros((19, 3)), np.full((19, 4), 2.0)))


def test_pose_offsets_decode_from_the_root() -> None:
    pos = reference_offsets().cumsum(axis=0) + np.array([0.0, 1.0, 0.0])
    out = decode(encode(Pose("p", 1, 1.0, pos)))
    assert isinstance(out, Pose) and out.rotations is None
    np.testing.assert_allclose(out.positions, pos, atol=5e-4)


def test_the_int16_helpers_invert_each_other(rng: np.random.Generator) -> None:
    positions = rng.uniform(-1, 1, (19, 3)) + np.array([3.0, 1.0, -2.0])
    root, pos_mm = pos2mm(positions)
    assert len(pos_mm) == POS_BYTES == 108 and root == positions[0].tolist()
    back = mm2pos(np.array(root), pos_mm)
    assert back[0].tolist() == root and np.abs(back - positions).max() <= 0.0005 + 1e-9
    quats = _unit_quats(rng, 19)
    blob = quat2snorm(quats)
    assert len(blob) == ROT_BYTES == 152
    np.testing.assert_allclose(snorm2quat(blob), quats, rtol=0, atol=0.5 / 32767 + 1e-12)
    assert quat2snorm(snorm2quat(blob)) == blob  # no renormalising: bytes survive
