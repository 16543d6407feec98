"""ONNX Runtime against torch on fixed inputs, for every exported graph."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import pytest
import torch

from posecast.offline.nets.anomaly import AnomalyAE, AnomalyConfig
from posecast.offline.nets.cvae import CVAE, CVAEConfig
from posecast.offline.train.checkpoint import save_checkpoint
from posecast.offline.train.export import build_ae_step, build_anomaly, build_decoder, export_all
from posecast.skeleton import JOINT_NAMES
from posecast.tracking.features import FEATURE_NAMES

ATOL = 1e-4


def _norm(rng: np.random.Generator, n_feat: int = 24, n_pose: int = 57) -> dict[str, list[float]]:
    return {
        "feat_mean": rng.normal(size=n_feat).tolist(),
        "feat_std": rng.uniform(0.5, 2.0, n_feat).tolist(),
        "pose_mean": rng.normal(size=n_pose).tolist(),
        "pose_std": rng.uniform(0.5, 2.0, n_pose).tolist(),
    }


def _ckpt(model: torch.nn.Module, cfg: Any, rng: np.random.Generator) -> dict[str, Any]:
    return {"model": model.state_dict(), "config": cfg.to_dict(), "norm": _norm(rng)}


def _session(model: Any) -> ort.InferenceSession:
    return ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])


def _n(ckpt: dict[str, Any], key: str) -> np.ndarray:
    return np.asarray(ckpt["norm"][key], np.float32)


def test_decoder_parity() -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = CVAE(CVAEConfig()).eval()
    ckpt = _ckpt(model, model.cfg, rng)
    x = rng.normal(size=(16, 24)).astype(np.float32)
    z = rng.normal(size=(16, 30)).astype(np.float32)
    h = rng.normal(size=(16, 128)).astype(np.float32) * 0.5
    rot, con, h_out = _session(build_decoder(ckpt)).run(None, {"features": x, "z": z, "h": h})
    xn = (x - _n(ckpt, "feat_mean")) / _n(ckpt, "feat_std")
    with torch.no_grad():
        ref = model.decoder.step(torch.from_numpy(xn), torch.from_numpy(z), torch.from_numpy(h))
    for got, want in zip((rot, con, h_out), ref, strict=True):
        np.testing.assert_allclose(got, want.numpy(), atol=ATOL, rtol=0)


def test_ae_step_parity() -> None:
    torch.manual_seed(1)
    rng = np.random.default_rng(1)
    cfg = CVAEConfig(deterministic=True, encoder_sees_pose=False)
    model = CVAE(cfg).eval()
    ckpt = _ckpt(model, cfg, rng)
    x = rng.normal(size=(8, 24)).astype(np.float32)
    he = rng.normal(size=(8, 128)).astype(np.float32) * 0.5
    hd = rng.normal(size=(8, 128)).astype(np.float32) * 0.5
    out = _session(build_ae_step(ckpt)).run(None, {"features": x, "h_enc": he, "h_dec": hd})
    xn = torch.from_numpy((x - _n(ckpt, "feat_mean")) / _n(ckpt, "feat_std"))
    with torch.no_grad():
        z, _, he_out = model.encoder(xn[:, None], torch.from_numpy(he)[None])
        rot, con, hd_out = model.decoder.step(xn, z[:, 0], torch.from_numpy(hd))
    for got, want in zip(out, (rot, con, he_out[0], hd_out), strict=True):
        np.testing.assert_allclose(got, want.numpy(), atol=ATOL, rtol=0)


def test_anomaly_parity() -> None:
    torch.manual_seed(2)
    rng = np.random.default_rng(2)
    model = AnomalyAE(AnomalyConfig()).eval()
    ckpt = _ckpt(model, model.cfg, rng)
    pos = rng.normal(size=(32, 57)).astype(np.float32)
    (rot,) = _session(build_anomaly(ckpt)).run(None, {"local_positions": pos})
    xn = (pos - _n(ckpt, "pose_mean")) / _n(ckpt, "pose_std")
    with torch.no_grad():
        ref = model(torch.from_numpy(xn)).numpy()
    np.testing.assert_allclose(rot, ref, atol=ATOL, rtol=0)


def test_decoder_graph_has_no_fused_gru() -> None:
    torch.manual_seed(0)
    model = CVAE(CVAEConfig())
    graph = build_decoder(_ckpt(model, model.cfg, np.random.default_rng(0))).graph
    kinds = {n.op_type for n in graph.node}
    assert "GRU" not in kinds and "Gemm" in kinds


def test_export_all_writes_sidecars(tmp_path: Path) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    model = CVAE(CVAEConfig())
    ckpt = _ckpt(model, model.cfg, rng) | {"step": 3, "train_config": {"steps": 3}}
    save_checkpoint(tmp_path / "c.pt", ckpt)
    extra = {"cvae_decoder": {"mean_pose_rot6d": [0.0] * 108}}
    written = export_all(tmp_path / "models", cvae=tmp_path / "c.pt", extra=extra)
    assert sorted(p.name for p in written) == ["cvae_decoder.json", "cvae_decoder.onnx"]
    meta = json.loads((tmp_path / "models" / "cvae_decoder.json").read_text())
    assert meta["joint_order"] == list(JOINT_NAMES)
    assert meta["feature_layout"] == list(FEATURE_NAMES)
    assert meta["inputs"] == {"features": ["B", 24], "z": ["B", 30], "h": ["B", 128]}
    assert meta["outputs"]["rotations"] == ["B", 108]
    assert len(meta["skeleton_offsets_m"]) == 19
    assert meta["normalisation"]["feat_std"] == pytest.approx(ckpt["norm"]["feat_std"])
    assert meta["training"]["steps"] == 3
    assert meta["mean_pose_rot6d"] == [0.0] * 108
    assert meta["git_revision"]


def test_hmd3_decoder_parity_and_sidecar(tmp_path: Path) -> None:
    """The headset-only decoder: 36 features in, the pelvis as its own ``root`` output,
    equal to torch's 9 extra pose-head outputs."""
    from posecast.tracking.features import FEATURE_NAMES_HMD3

    torch.manual_seed(1)
    rng = np.random.default_rng(1)
    model = CVAE(CVAEConfig(n_features=36, layout="hmd3", root_outputs=9)).eval()
    ckpt = {"model": model.state_dict(), "config": model.cfg.to_dict(), "norm": _norm(rng, 36)}
    x = rng.normal(size=(8, 36)).astype(np.float32)
    z = rng.normal(size=(8, 30)).astype(np.float32)
    h = rng.normal(size=(8, 128)).astype(np.float32) * 0.5
    sess = _session(build_decoder(ckpt))
    assert [o.name for o in sess.get_outputs()] == ["rotations", "root", "contacts", "h_out"]
    rot, root, con, h_out = sess.run(None, {"features": x, "z": z, "h": h})
    xn = (x - _n(ckpt, "feat_mean")) / _n(ckpt, "feat_std")
    with torch.no_grad():
        r, c, hh = model.decoder.step(
            torch.from_numpy(xn), torch.from_numpy(z), torch.from_numpy(h)
        )
    np.testing.assert_allclose(rot, r[:, :108].numpy(), atol=ATOL, rtol=0)
    np.testing.assert_allclose(root, r[:, 108:].numpy(), atol=ATOL, rtol=0)
    np.testing.assert_allclose(con, c.numpy(), atol=ATOL, rtol=0)
    np.testing.assert_allclose(h_out, hh.numpy(), atol=ATOL, rtol=0)
    save_checkpoint(tmp_path / "c3.pt", ckpt)
    export_all(tmp_path / "models", cvae_hmd3=tmp_path / "c3.pt")
    meta = json.loads((tmp_path / "models" / "cvae_decoder_hmd3.json").read_text())
    assert meta["layout"] == "hmd3" and meta["feature_layout"] == list(FEATURE_NAMES_HMD3)
    assert meta["outputs"]["root"] == ["B", 9]
    assert sorted(meta["tracker_slots"]) == ["HEAD", "LEFT_HAND", "RIGHT_HAND"]
