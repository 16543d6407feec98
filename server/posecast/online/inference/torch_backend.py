"""The ``torch`` backend: the training code's own ``CVAEDecoder.step`` on the exported weights.

For parity and research, not for speed. The weights come from the same ONNX file the
``onnx`` backend runs (the one source of weights, read with the ``onnx`` package), put
back into :class:`posecast.offline.nets.cvae.CVAEDecoder`; the candidate pool is the numpy
one. Needs ``posecast[train]`` (torch and onnx);
:func:`posecast.online.inference.auto.load_backend` says so when they are missing.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from posecast.errors import ModelError
from posecast.offline.nets.cvae import CVAEConfig, CVAEDecoder
from posecast.online.engine.ports import F32, Models
from posecast.online.inference.artifact import load_artifact, read_sidecar
from posecast.online.inference.onnx_backend import NumpyPool


def _initializers(path: Path) -> dict[str, np.ndarray]:
    try:
        graph = onnx.load(str(path)).graph
    except Exception as exc:  # onnx raises DecodeError and friends, unexported
        raise ModelError(f"cannot read ONNX model: {exc}", path=path) from exc
    return {t.name: numpy_helper.to_array(t) for t in graph.initializer}


def _pose_head(w: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The pose head's ``(out, in)`` weight and bias. The hmd3 export splits it into the
    108 joint rotations and the 9 pelvis outputs (``weight_t_0_108``, ``_108_117``)."""
    if "decoder.pose.weight_t" in w:
        return w["decoder.pose.weight_t"].T, w["decoder.pose.bias"]
    parts = sorted(
        (int(k.rsplit("_", 2)[-2]), k[len("decoder.pose.weight_t") :])
        for k in w
        if k.startswith("decoder.pose.weight_t_")
    )
    weight = np.concatenate([w[f"decoder.pose.weight_t{tag}"].T for _, tag in parts], axis=0)
    bias = np.concatenate([w[f"decoder.pose.bias{tag}"] for _, tag in parts])
    return weight, bias


class TorchDecoder:
    """A :class:`~posecast.online.engine.ports.StepDecoder` running ``CVAEDecoder.step`` in torch.

    The cache is ``eps`` itself. Each step runs under ``torch.no_grad()`` on one
    thread: torch's thread count is process-wide, so it is set for the call and put
    back after (a training run in the same process keeps its own).
    """

    def __init__(self, name: str, meta: dict[str, Any], weights: dict[str, np.ndarray]) -> None:
        self.name, self.meta = name, meta
        mc = meta["model_config"]
        n_feat = len(meta["feature_layout"])
        try:
            pose_w, pose_b = _pose_head(weights)
            cfg = CVAEConfig(
                n_features=n_feat,
                latent=int(mc["latent"]),
                hidden=int(mc["hidden"]),
                layout=str(meta.get("layout", CVAEConfig.layout)),
                root_outputs=pose_w.shape[0] - 108,
            )
            net = CVAEDecoder(cfg)
            w = weights
            state = {
                # (hidden, F + latent): the export split the first layer by input.
                "fc.weight": np.concatenate([w["decoder.fc.wx_t"].T, w["decoder.fc.wz_t"].T], 1),
                "fc.bias": w["decoder.fc.bias"],
                "gru.weight_ih_l0": w["decoder.gru.w_ih_t"].T,  # (3H, H): gates r, u, n
                "gru.bias_ih_l0": w["decoder.gru.b_ih"],
                "gru.weight_hh_l0": w["decoder.gru.w_hh_t"].T,
                "gru.bias_hh_l0": w["decoder.gru.b_hh"],
                "pose.weight": pose_w,
                "pose.bias": pose_b,
                "contact.weight": w["decoder.contact.weight_t"].T,
                "contact.bias": w["decoder.contact.bias"],
            }
            net.load_state_dict(
                {k: torch.from_numpy(np.array(v, np.float32)) for k, v in state.items()}
            )
            self._mean = torch.from_numpy(np.array(w["feat.mean"], np.float32))
            self._inv_std = torch.from_numpy(np.array(w["feat.inv_std"], np.float32))
        except (KeyError, ValueError, RuntimeError) as exc:
            raise ModelError(f"{name}: not a posecast decoder graph ({exc})") from exc
        self.net = net.eval()
        self.cache_width = cfg.latent

    def cache_latents(self, eps: F32) -> F32:
        return np.array(eps, dtype=np.float32)

    def step(self, features: F32, group: int, cache: F32, h: F32, out: Mapping[str, F32]) -> None:
        threads = torch.get_num_threads()
        if threads != 1:
            torch.set_num_threads(1)
        try:
            with torch.no_grad():
                x = (_tensor(features) - self._mean) * self._inv_std
                if group > 1:  # one feature row per decoded row: (G, F) -> (G * group, F)
                    x = x.repeat_interleave(group, dim=0)
                pose, contacts, h_new = self.net.step(x, _tensor(cache), _tensor(h))
                # (R, 108 [+ 9]), (R, 2), (R, H)
                out["rotations"][...] = pose[:, :108].numpy()
                if "root" in out:
                    out["root"][...] = pose[:, 108:].numpy()
                out["contacts"][...] = contacts.numpy()
                out["h_out"][...] = h_new.numpy()
        finally:
            if threads != 1:
                torch.set_num_threads(threads)


def _tensor(a: np.ndarray) -> torch.Tensor:
    """A float32 tensor sharing ``a``'s memory where it can (no copy for the ring rows)."""
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


def load_torch(m: Models) -> tuple[TorchDecoder, NumpyPool]:
    """The ``torch`` backend on the artifacts ``m`` names (``m.threads``: of the anomaly
    network's ONNX Runtime session; the decoder runs on one)."""
    meta, onnx_path = read_sidecar(m.decoder, m.models_dir)
    dec = TorchDecoder(m.decoder, meta, _initializers(onnx_path))
    scorer = load_artifact(m.anomaly, m.models_dir, threads=m.threads)
    return dec, NumpyPool(scorer, m.release_frames, m.max_drift_m)
