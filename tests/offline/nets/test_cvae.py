from __future__ import annotations

import pytest
import torch

from posecast.offline.nets.cvae import CVAE, CVAEConfig


@pytest.fixture
def model() -> CVAE:
    torch.manual_seed(0)
    return CVAE(CVAEConfig()).eval()


def test_shapes(model: CVAE) -> None:
    x = torch.randn(3, 7, 24)  # (B, T, 24)
    pose = torch.randn(3, 7, 57)
    rot, logits, kl = model(x, pose)
    assert rot.shape == (3, 7, 108)  # 18 joints x 6D: the paper's r_t, not "54 outputs"
    assert logits.shape == (3, 7, 2)
    assert kl.shape == (3, 7)
    assert torch.all(kl >= 0)


def test_decoder_step_matches_whole_sequence(model: CVAE) -> None:
    """The GRU stepped frame by frame (as exported) equals nn.GRU over the sequence."""
    torch.manual_seed(1)
    x, z = torch.randn(4, 25, 24), torch.randn(4, 25, 30)
    with torch.no_grad():
        rot_seq, logit_seq, h_last = model.decoder(x, z)
        h = torch.zeros(4, 128)
        for t in range(25):
            rot, prob, h = model.decoder.step(x[:, t], z[:, t], h)
            torch.testing.assert_close(rot, rot_seq[:, t], atol=1e-5, rtol=0)
            torch.testing.assert_close(prob, torch.sigmoid(logit_seq[:, t]), atol=1e-5, rtol=0)
    torch.testing.assert_close(h, h_last[0], atol=1e-5, rtol=0)


def test_sampling_changes_output_only_through_z(model: CVAE) -> None:
    x, pose = torch.randn(2, 5, 24), torch.randn(2, 5, 57)
    with torch.no_grad():
        a, _, _ = model(x, pose, sample=False)
        b, _, _ = model(x, pose, sample=False)
        c, _, _ = model(x, pose, sample=True)
    torch.testing.assert_close(a, b)
    assert not torch.allclose(a, c)


def test_deterministic_variant_has_no_kl() -> None:
    torch.manual_seed(0)
    ae = CVAE(CVAEConfig(deterministic=True, encoder_sees_pose=False))
    rot, _, kl = ae(torch.randn(2, 4, 24))
    assert rot.shape == (2, 4, 108)
    assert torch.all(kl == 0)
    assert hasattr(ae.encoder, "z") and not hasattr(ae.encoder, "mu")


def test_ae_encoder_may_not_see_the_pose() -> None:
    with pytest.raises(ValueError):
        CVAEConfig(deterministic=True, encoder_sees_pose=True)


def test_pose_is_required_when_the_encoder_sees_it(model: CVAE) -> None:
    with pytest.raises(ValueError):
        model(torch.randn(1, 2, 24))
