from __future__ import annotations

import torch

from posecast.offline.nets.anomaly import AnomalyAE, AnomalyConfig


def test_layer_sizes_follow_the_paper() -> None:
    ae = AnomalyAE(AnomalyConfig())
    sizes = [(layer.in_features, layer.out_features) for layer in ae.layers]  # type: ignore[union-attr]
    assert sizes == [(57, 28), (28, 14), (14, 7), (7, 7), (7, 14), (14, 28), (28, 108)]


def test_output_is_not_rectified() -> None:
    torch.manual_seed(0)
    out = AnomalyAE(AnomalyConfig())(torch.randn(64, 57))
    assert out.shape == (64, 108)
    assert (out < 0).any()  # no ReLU on the last layer
