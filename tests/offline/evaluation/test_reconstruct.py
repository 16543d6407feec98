"""Single-sample reconstruction of whole clips (offline.evaluation.reconstruct): the
decoder stepped over a clip as the server steps it, the deterministic AE, FK on the
reference body, and a clip's ground truth (shipped models)."""

from __future__ import annotations

import numpy as np

from posecast.geometry.rotations import mat2r6d
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.evaluation.reconstruct import (
    clip_truth,
    decode_ae,
    decode_cvae,
    pose_from_rotations,
)
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.ports import Models
from posecast.online.inference.artifact import load_artifact
from posecast.online.inference.onnx_backend import load_onnx
from posecast.skeleton import PARENTS, reference_offsets
from posecast.tracking.layouts import Layout, spec

T = 12


def _walk() -> dict[str, np.ndarray]:
    return derive_frames(walk_clip(seconds=T / 60.0, fps=60.0, seed=1))


def test_a_clips_truth_is_fk_of_its_rotations() -> None:
    fr = _walk()
    mats, pos = clip_truth(fr)
    assert mats.shape == (T, 19, 3, 3) and pos.shape == (T, 19, 3)
    np.testing.assert_allclose(pos, fr["positions"], atol=1e-5)  # float32 frames


def test_fk_from_rest_rotations_is_the_reference_body_on_the_pelvis() -> None:
    rot6d = np.broadcast_to(mat2r6d(np.eye(3)), (2, 18, 6))
    root_pos = np.array([[0.0, 1.0, 0.0], [2.0, 1.0, -1.0]])
    mats, pos = pose_from_rotations(rot6d, np.broadcast_to(np.eye(3), (2, 3, 3)), root_pos)
    assert mats.shape == (2, 19, 3, 3)
    np.testing.assert_allclose(pos[:, 0], root_pos)
    np.testing.assert_allclose(mats, np.broadcast_to(np.eye(3), mats.shape), atol=1e-12)
    np.testing.assert_allclose(pos[1] - pos[0], np.broadcast_to([2.0, 0.0, -1.0], (19, 3)))
    parents_pos = pos[0, list(PARENTS[1:])]
    np.testing.assert_allclose(pos[0, 1:] - parents_pos, reference_offsets()[1:], atol=1e-12)


def test_the_decoder_steps_a_clip_as_the_server_steps_it() -> None:
    """Frame by frame with a fixed latent and the hidden state carried: the server's
    decoder (``onnx`` backend, one row) gives the same rotations and contacts; the
    headset-only model also returns its pelvis outputs."""
    fr = _walk()
    for layout in (Layout.HMD3_WAIST, Layout.HMD3):
        sp = spec(layout)
        features = sp.clip_features(fr["tracker_pos"], fr["tracker_quat"], 60.0).astype(np.float32)
        dec, _ = load_onnx(Models(sp.decoder, sp.anomaly))
        z = np.random.default_rng(0).normal(size=dec.cache_width).astype(np.float32)
        rot, con, root = decode_cvae(dec.artifact, features, z)
        assert rot.shape == (T, 18, 6) and con.shape == (T, 2)
        assert (root is None) == (not sp.predicts_root)
        if root is not None:
            assert root.shape == (T, sp.root_outputs)
        hidden = int(dec.meta["model_config"]["hidden"])
        h = np.zeros((1, hidden), np.float32)
        for t in range(T):
            out = {"rotations": np.zeros((1, 108), np.float32),
                   "contacts": np.zeros((1, 2), np.float32),
                   "h_out": np.zeros((1, hidden), np.float32)}  # fmt: skip
            if sp.predicts_root:
                out["root"] = np.zeros((1, sp.root_outputs), np.float32)
            dec.step(features[t : t + 1], 1, dec.cache_latents(z[None]), h, out)
            np.testing.assert_allclose(rot[t].reshape(108), out["rotations"][0], atol=1e-6)
            np.testing.assert_allclose(con[t], out["contacts"][0], atol=1e-6)
            if root is not None:
                np.testing.assert_allclose(root[t], out["root"][0], atol=1e-6)
            h = out["h_out"]


def test_the_autoencoder_carries_its_state_through_the_clip() -> None:
    fr = _walk()
    features = spec(Layout.HMD3_WAIST).clip_features(fr["tracker_pos"], fr["tracker_quat"], 60.0)
    step = load_artifact("ae_step")
    rot, con = decode_ae(step, features.astype(np.float32))
    assert rot.shape == (T, 18, 6) and con.shape == (T, 2) and np.isfinite(rot).all()
    again, _ = decode_ae(step, features.astype(np.float32))
    np.testing.assert_array_equal(rot, again)  # deterministic
    later, _ = decode_ae(step, features[4:].astype(np.float32))  # from a fresh state
    assert not np.allclose(later[0], rot[4], atol=1e-4)  # the state mattered
