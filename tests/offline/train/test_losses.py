"""The position-space losses (offline.train.losses): the velocity term, the joint
weights, FK from predicted rotations and the pelvis split."""

from __future__ import annotations

import numpy as np
import pytest


def test_the_velocity_term_scores_frame_to_frame_motion_only() -> None:
    import torch

    from posecast.offline.train.losses import velocity_mse_cm2

    g = torch.Generator().manual_seed(0)
    truth = torch.randn(2, 10, 19, 3, generator=g, dtype=torch.float64) * 0.1
    offset = truth + torch.tensor([0.05, -0.02, 0.01], dtype=torch.float64)  # 5 cm off, steady
    assert float(velocity_mse_cm2(offset, truth)) == pytest.approx(0.0, abs=1e-9)
    jitter = truth.clone()
    jitter[:, 1::2, :, 1] += 0.01  # every other frame 1 cm up: each displacement is 1 cm off in y
    assert float(velocity_mse_cm2(jitter, truth)) == pytest.approx(1.0 / 3.0)


def test_position_error_is_in_square_centimetres_and_weights_are_normalised() -> None:
    import torch

    from posecast.offline.train.losses import position_mse_cm2

    truth = torch.zeros(2, 4, 19, 3, dtype=torch.float64)
    off = truth.clone()
    off[..., 0] = 0.02  # every joint 2 cm off in x: 4 cm^2 on one axis of three
    assert float(position_mse_cm2(off, truth)) == pytest.approx(4.0 / 3.0)
    even = torch.full((19,), 5.0, dtype=torch.float64)
    assert float(position_mse_cm2(off, truth, even)) == pytest.approx(4.0 / 3.0)
    one = truth.clone()
    one[..., 7, 1] = 0.01  # 1 cm on joint 7 alone
    w = torch.ones(19, dtype=torch.float64)
    w[7] = 4.0
    plain = float(position_mse_cm2(one, truth))
    assert plain == pytest.approx(1.0 / (19 * 3))
    assert float(position_mse_cm2(one, truth, w)) == pytest.approx(plain * 4.0 / float(w.mean()))


def test_pose_fk_puts_the_joints_where_numpy_fk_does() -> None:
    import torch

    from posecast.geometry.fk import fk_mat
    from posecast.geometry.rotations import mat2r6d, quat2mat
    from posecast.offline.train.losses import PoseFK
    from posecast.skeleton import reference_offsets

    rng = np.random.default_rng(0)
    q = rng.normal(size=(3, 19, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    local = quat2mat(q)  # (3, 19, 3, 3)
    root_pos = rng.normal(size=(3, 3))
    _, want = fk_mat(local, root_pos, reference_offsets())
    rot6d = torch.tensor(mat2r6d(local[:, 1:]).reshape(3, 108), dtype=torch.float32)
    got = PoseFK()(
        rot6d,
        torch.tensor(local[:, 0], dtype=torch.float32),
        torch.tensor(root_pos, dtype=torch.float32),
    )
    assert got.shape == (3, 19, 3)
    np.testing.assert_allclose(got.numpy(), want, atol=1e-5)


def test_split_root_takes_the_pelvis_from_the_data_or_the_output() -> None:
    import torch

    from posecast.geometry.rotations import mat2r6d
    from posecast.offline.train.losses import split_root

    root_mat, root_pos = torch.eye(3).expand(2, 3, 3), torch.zeros(2, 3)
    pose = torch.randn(2, 108, generator=torch.Generator().manual_seed(0))
    out, m, p = split_root(pose, root_mat, root_pos)
    assert out is pose and m is root_mat and p is root_pos
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    tail = torch.tensor(np.concatenate([mat2r6d(turn), [0.1, 0.9, -0.2]]), dtype=torch.float32)
    full = torch.cat([pose, tail.expand(2, 9)], dim=-1)  # (2, 117)
    out, m, p = split_root(full, root_mat, root_pos)
    assert torch.equal(out, pose)
    np.testing.assert_allclose(m.numpy(), np.broadcast_to(turn, (2, 3, 3)), atol=1e-6)
    np.testing.assert_allclose(p.numpy(), [[0.1, 0.9, -0.2]] * 2, atol=1e-7)
