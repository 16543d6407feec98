"""The torch twins agree with the numpy reference and carry gradients."""

from __future__ import annotations

import numpy as np
import torch

from posecast.geometry import rotations, torch_ops
from posecast.geometry.fk import fk_mat
from posecast.skeleton import NUM_JOINTS, Joint, children

BATCH = 7


def random_rotations(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return rotations.quat2mat(rotations.normalize(rng.normal(size=(*shape, 4))))


def test_r6d2mat_parity(rng: np.random.Generator) -> None:
    d = rng.normal(size=(BATCH, NUM_JOINTS, 6)) * 2.0
    got = torch_ops.r6d2mat(torch.from_numpy(d)).numpy()
    np.testing.assert_allclose(got, rotations.r6d2mat(d), atol=1e-12)


def test_mat2r6d_parity(rng: np.random.Generator) -> None:
    m = random_rotations(rng, (BATCH, NUM_JOINTS))
    got = torch_ops.mat2r6d(torch.from_numpy(m)).numpy()
    np.testing.assert_array_equal(got, rotations.mat2r6d(m))


def test_fk_parity(rng: np.random.Generator) -> None:
    local = random_rotations(rng, (BATCH, NUM_JOINTS))
    root = rng.normal(size=(BATCH, 3))
    offsets = rng.normal(size=(NUM_JOINTS, 3)) * 0.3
    want_mat, want_pos = fk_mat(local, root, offsets)
    got_mat, got_pos = torch_ops.fk(
        torch.from_numpy(local), torch.from_numpy(root), torch.from_numpy(offsets)
    )
    assert got_mat.dtype == torch.float64
    assert tuple(got_pos.shape) == (BATCH, NUM_JOINTS, 3)
    np.testing.assert_allclose(got_mat.numpy(), want_mat, atol=1e-5)
    np.testing.assert_allclose(got_pos.numpy(), want_pos, atol=1e-5)


def test_fk_parity_with_per_sample_offsets(rng: np.random.Generator) -> None:
    local = random_rotations(rng, (BATCH, NUM_JOINTS))
    root = rng.normal(size=(BATCH, 3))
    offsets = rng.normal(size=(BATCH, NUM_JOINTS, 3)) * 0.3
    _, want = fk_mat(local, root, offsets)
    _, got = torch_ops.fk(
        torch.from_numpy(local), torch.from_numpy(root), torch.from_numpy(offsets)
    )
    np.testing.assert_allclose(got.numpy(), want, atol=1e-5)


def test_fk_backpropagates_to_6d(rng: np.random.Generator) -> None:
    """A position loss on FK of 6D outputs gives finite, non-zero 6D gradients."""
    d = torch.tensor(rng.normal(size=(BATCH, NUM_JOINTS, 6)), requires_grad=True)
    root = torch.tensor(rng.normal(size=(BATCH, 3)))
    offsets = torch.tensor(rng.normal(size=(NUM_JOINTS, 3)) * 0.3)
    _, pos = torch_ops.fk(torch_ops.r6d2mat(d), root, offsets)
    target = torch.tensor(rng.normal(size=(BATCH, NUM_JOINTS, 3)))
    ((pos - target) ** 2).sum().backward()
    assert d.grad is not None
    assert torch.isfinite(d.grad).all()
    # A joint's rotation moves its descendants only: leaves get no position gradient.
    moved = d.grad.abs().sum(dim=(0, 2)) > 0
    for j in Joint:
        assert bool(moved[j]) == bool(children(j)), j.name


def test_fk_gradient_matches_finite_differences(rng: np.random.Generator) -> None:
    root = torch.zeros(1, 3, dtype=torch.float64)
    offsets = torch.tensor(rng.normal(size=(NUM_JOINTS, 3)) * 0.3)

    def positions(d: torch.Tensor) -> torch.Tensor:
        return torch_ops.fk(torch_ops.r6d2mat(d), root, offsets)[1]

    d = torch.tensor(rng.normal(size=(1, NUM_JOINTS, 6)), requires_grad=True)
    assert torch.autograd.gradcheck(positions, (d,), eps=1e-6, atol=1e-6)
