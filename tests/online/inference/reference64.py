"""A float64 reference of one SSI tick's math, from the shipped ONNX weights.

Written out from the decoder graph (posecast/offline/nets/cvae.py ``CVAEDecoder.step``),
the float64 FK of :mod:`posecast.geometry.fk`, :class:`posecast.body.ik.ContactIK`
on float64 arrays and the anomaly score of :mod:`posecast.online.inference.anomaly`, so
the native kernels are checked against something that shares none of their code.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import onnx
from numpy.typing import NDArray
from onnx import numpy_helper

from posecast.body.ik import ContactIK
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import quat2mat, r6d2mat
from posecast.online.inference.artifact import default_models_dir
from posecast.skeleton import LOWER_BODY, reference_offsets

F = NDArray[np.float64]


def sidecar(name: str) -> dict[str, Any]:
    out: dict[str, Any] = json.loads((default_models_dir() / f"{name}.json").read_text())
    return out


def weights(name: str) -> dict[str, F]:
    model = onnx.load(str(default_models_dir() / f"{name}.onnx"))
    return {i.name: numpy_helper.to_array(i).astype(np.float64) for i in model.graph.initializer}


def _sigmoid(x: F) -> F:
    out: F = 0.5 * (1.0 + np.tanh(0.5 * x))  # no overflow for large |x|
    return out


@dataclass
class Decoder64:
    w: dict[str, F]
    n_features: int
    latent: int
    hidden: int
    n_root: int

    @classmethod
    def load(cls, name: str) -> Decoder64:
        mc = sidecar(name)["model_config"]
        return cls(
            weights(name),
            int(mc["n_features"]),
            int(mc["latent"]),
            int(mc["hidden"]),
            int(mc.get("root_outputs", 0)),
        )

    def step(self, x: F, group: int, eps: F, h: F) -> tuple[F, F, F, F | None]:
        w, H = self.w, self.hidden
        xn = np.repeat((x - w["feat.mean"]) * w["feat.inv_std"], group, axis=0)
        f = np.maximum(
            xn @ w["decoder.fc.wx_t"] + eps @ w["decoder.fc.wz_t"] + w["decoder.fc.bias"], 0
        )
        gi = f @ w["decoder.gru.w_ih_t"] + w["decoder.gru.b_ih"]
        gh = h @ w["decoder.gru.w_hh_t"] + w["decoder.gru.b_hh"]
        r = _sigmoid(gi[:, :H] + gh[:, :H])
        u = _sigmoid(gi[:, H : 2 * H] + gh[:, H : 2 * H])
        n = np.tanh(gi[:, 2 * H :] + r * gh[:, 2 * H :])
        h_new = n + u * (h - n)
        a = np.maximum(h_new, 0)
        con = _sigmoid(a @ w["decoder.contact.weight_t"] + w["decoder.contact.bias"])
        if self.n_root:
            rot = a @ w["decoder.pose.weight_t_0_108"] + w["decoder.pose.bias_0_108"]
            root = a @ w["decoder.pose.weight_t_108_117"] + w["decoder.pose.bias_108_117"]
            return rot, con, h_new, root
        return rot_head(a, w), con, h_new, None


def rot_head(a: F, w: dict[str, F]) -> F:
    # The exporter names the pose head plainly or by the slice its graph takes (_0_108).
    sfx = "" if "decoder.pose.weight_t" in w else "_0_108"
    out: F = a @ w["decoder.pose.weight_t" + sfx] + w["decoder.pose.bias" + sfx]
    return out


def quat2mat64(q: F) -> F:
    return quat2mat(q)


def _fk(rot6d: F, root_mat: F, root_pos: F) -> F:
    local = np.concatenate([root_mat[:, None], r6d2mat(rot6d.reshape(-1, 18, 6))], axis=1)
    _, pos = fk_mat(local, root_pos, reference_offsets())
    return pos


def fk_positions64(rot6d: F) -> F:
    """Joint positions of rows of 6D rotations with the pelvis at the origin, upright."""
    B = len(rot6d)
    return _fk(rot6d, np.broadcast_to(np.eye(3), (B, 3, 3)), np.zeros((B, 3)))


def pool64(
    rot: F,
    con: F,
    root_mat: F,
    root_pos: F,
    ik: dict[str, NDArray[Any]],
    release_frames: int,
    max_drift_m: float | None,
) -> tuple[F, F]:
    """Post-IK world positions ``(R, 19, 3)`` and anomaly errors ``(R,)`` in float64;
    ``ik`` (locked, lock_pos, release, suppressed) steps in place."""
    wp = _fk(rot, root_mat, root_pos)
    ContactIK(
        ik["locked"], ik["lock_pos"], ik["release"], release_frames, ik["suppressed"], max_drift_m
    ).step(None, wp, con)
    yaw = np.arctan2(root_mat[:, 0, 2], root_mat[:, 2, 2])
    c, s = np.cos(yaw), np.sin(yaw)
    z, o = np.zeros_like(c), np.ones_like(c)
    inv_yaw = np.stack([c, z, -s, z, o, z, s, z, c], axis=-1).reshape(-1, 3, 3)
    deyawed = inv_yaw @ root_mat
    rel = wp - np.stack([root_pos[:, 0], z, root_pos[:, 2]], axis=-1)[:, None]
    local = np.stack([c[:, None] * rel[..., 0] - s[:, None] * rel[..., 2], rel[..., 1],
                      s[:, None] * rel[..., 0] + c[:, None] * rel[..., 2]], axis=-1)  # fmt: skip
    w = weights("anomaly")
    x = (local.reshape(-1, 57) - w["pose.mean"]) * w["pose.inv_std"]
    for i in range(7):
        x = x @ w[f"layers.{i}.weight_t"] + w[f"layers.{i}.bias"]
        if i < 6:
            x = np.maximum(x, 0)
    rec = _fk(x, deyawed, local[:, 0])
    lower = [int(j) for j in LOWER_BODY]
    err: F = np.linalg.norm(rec[:, lower] - local[:, lower], axis=-1).mean(axis=-1)
    return wp, err
