"""The onnx backend (online.inference.onnx_backend): the decoder repeats each feature row
for its samples, and the numpy pool's FK, contact IK and scores of rows that share a
pelvis are those of rows that each carry it (shipped models)."""

from __future__ import annotations

import numpy as np

from posecast.body.batch_fk import fk32
from posecast.body.passes import PoolIK
from posecast.body.pelvis import PelvisPoses
from posecast.geometry.rotations import mat2r6d
from posecast.online.engine.ports import Models
from posecast.online.inference.artifact import load_artifact
from posecast.online.inference.onnx_backend import NumpyPool, OnnxDecoder, load_onnx
from posecast.skeleton import NUM_JOINTS

G, GROUP = 3, 4
R = G * GROUP


def _decoder_inputs(dec: OnnxDecoder) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    norm = dec.meta["normalisation"]
    mean, std = np.asarray(norm["feat_mean"]), np.asarray(norm["feat_std"])
    features = (mean + rng.normal(size=(G, len(mean))) * std).astype(np.float32)
    eps = rng.normal(size=(R, dec.cache_width)).astype(np.float64)
    h = np.tanh(rng.normal(size=(R, int(dec.meta["model_config"]["hidden"])))).astype(np.float32)
    return features, eps, h


def _out(dec: OnnxDecoder) -> dict[str, np.ndarray]:
    hidden = int(dec.meta["model_config"]["hidden"])
    return {k: np.full((R, w), np.nan, np.float32) for k, w in
            (("rotations", 108), ("contacts", 2), ("h_out", hidden))}  # fmt: skip


def test_the_decoder_shares_a_feature_row_among_its_group() -> None:
    dec, pool = load_onnx(Models("cvae_decoder", "anomaly"))
    assert dec.name == "cvae_decoder" and pool.threshold_m == pool.scorer.threshold_m > 0
    features, eps, h = _decoder_inputs(dec)
    cache = dec.cache_latents(eps)
    assert cache.dtype == np.float32 and cache.shape == eps.shape and cache is not eps
    grouped, repeated = _out(dec), _out(dec)
    dec.step(features, GROUP, cache, h, grouped)
    dec.step(np.repeat(features, GROUP, axis=0), 1, cache, h, repeated)
    for name in grouped:
        assert np.isfinite(grouped[name]).all(), name
        np.testing.assert_array_equal(grouped[name], repeated[name], err_msg=name)
    rows = grouped["rotations"].reshape(G, GROUP, 108)
    assert not np.allclose(rows[:, 0], rows[:, 1])  # each sample its own latent


def test_the_pool_scores_rows_that_share_a_pelvis_as_rows_that_each_carry_it() -> None:
    pool = NumpyPool(load_artifact("anomaly"))
    rng = np.random.default_rng(1)
    rot = np.broadcast_to(mat2r6d(np.eye(3)), (R, 18, 6)).reshape(R, 108)
    rot = (rot + rng.normal(scale=0.05, size=rot.shape)).astype(np.float32)
    contacts = rng.random((R, 2)).astype(np.float32)
    mats = np.broadcast_to(np.eye(3, dtype=np.float32), (G, 3, 3)).copy()
    places = np.array([[0.0, 0.95, 0.0], [1.0, 0.9, 0.0], [2.0, 1.0, 0.5]], np.float32)
    shared_out = np.zeros((R, NUM_JOINTS, 3), np.float32)
    shared = pool.step(rot, contacts, PelvisPoses(mats, places, GROUP), PoolIK.zeros(R), shared_out)
    each_out = np.zeros_like(shared_out)
    each = pool.step(
        rot, contacts,
        PelvisPoses(np.repeat(mats, GROUP, axis=0), np.repeat(places, GROUP, axis=0), 1),
        PoolIK.zeros(R), each_out,
    )  # fmt: skip
    assert shared.shape == (R,) and shared.dtype == np.float64 and np.isfinite(shared).all()
    np.testing.assert_allclose(shared, each, rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(shared_out, each_out)
    # on a first frame no foot was locked before: the world positions are FK's (to
    # float32's rounding at a metre)
    _, wp = fk32(rot, np.repeat(mats, GROUP, axis=0), np.repeat(places, GROUP, axis=0), False)
    np.testing.assert_allclose(shared_out, wp, atol=1e-5)
    np.testing.assert_allclose(
        shared_out[GROUP : 2 * GROUP, 0], np.broadcast_to(places[1], (GROUP, 3)), atol=1e-6
    )
