"""Export trained checkpoints to ONNX plus a JSON sidecar each.

The graphs are written node by node from the trained weights rather than traced:
the decoder's GRU step becomes plain Gemm and elementwise nodes, which ONNX Runtime
runs about 3x faster than its fused ``GRU`` operator at serving shapes (see
``../shared/notes/engine-performance.md``), and the first layer is split into a
tracker part and a latent part so the engine can precompute the latent part once per
connection. Input normalisation is inside the graph: callers feed raw features.

Artifacts (in ``posecast/artifacts``):

* ``cvae_decoder.onnx``: ``features (B,24), z (B,30), h (B,128)`` ->
  ``rotations (B,108), contacts (B,2), h_out (B,128)``
* ``cvae_decoder_hmd3.onnx`` (headset only): ``features (B,36), z, h`` ->
  ``rotations (B,108), root (B,9), contacts, h_out``; ``root`` is the pelvis rotation
  (6D) and position (metres) in the head's yaw frame
* ``cvae_decoder_sites.onnx`` (every tracker set, :mod:`posecast.tracking.sites`):
  ``features (B,170), z, h`` -> ``rotations, root (B,9), contacts, h_out``, as the
  headset-only decoder; its normalisation is a scale only (absent sites read 0)
* ``ae_step.onnx`` (the deterministic ablation, encoder included):
  ``features (B,24), h_enc (B,128), h_dec (B,128)`` ->
  ``rotations, contacts, h_enc_out, h_dec_out``
* ``anomaly.onnx``: ``local_positions (B,57)`` -> ``rotations (B,108)``
"""

from __future__ import annotations

import datetime as _dt
import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from posecast import __version__
from posecast.offline.train.checkpoint import load_checkpoint
from posecast.skeleton import JOINT_NAMES, PARENTS, reference_offsets
from posecast.tracking.features import FEATURE_NAMES, TRACKER_JOINT
from posecast.tracking.layouts import Layout, spec
from posecast.tracking.sites import SITE_JOINT, SITES

OPSET = 17
ARTIFACT_FORMAT = "posecast-model"
ARTIFACT_VERSION = 1


class _Graph:
    """A tiny builder: named initializers and nodes, in order."""

    def __init__(self) -> None:
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []
        self._n = 0

    def const(self, name: str, value: Any) -> str:
        arr = np.asarray(value)
        arr = arr.astype(np.int64 if arr.dtype.kind == "i" else np.float32)
        self.inits.append(numpy_helper.from_array(arr, name))
        return name

    def op(self, kind: str, inputs: list[str], out: str | None = None, **attrs: Any) -> str:
        self._n += 1
        name = out or f"{kind.lower()}_{self._n}"
        self.nodes.append(helper.make_node(kind, inputs, [name], **attrs))
        return name

    def split3(self, x: str, width: int) -> list[str]:
        self._n += 1
        outs = [f"split_{self._n}_{k}" for k in range(3)]
        sizes = self.const(f"split_sizes_{self._n}", [width] * 3)
        self.nodes.append(helper.make_node("Split", [x, sizes], outs, axis=1))
        return outs

    def linear(
        self, x: str, sd: dict[str, np.ndarray], prefix: str, rows: slice = slice(None)
    ) -> str:
        """``x @ W[rows].T + b[rows]`` for the torch Linear ``prefix``."""
        tag = "" if rows == slice(None) else f"_{rows.start}_{rows.stop}"
        w = self.const(f"{prefix}.weight_t{tag}", sd[f"{prefix}.weight"][rows].T)
        b = self.const(f"{prefix}.bias{tag}", sd[f"{prefix}.bias"][rows])
        return self.op("Gemm", [x, w, b])

    def gru_step(self, f: str, h: str, sd: dict[str, np.ndarray], prefix: str, out: str) -> str:
        """torch.nn.GRU's single-layer step, gates ordered r, u (update), n."""
        H = sd[f"{prefix}.weight_hh_l0"].shape[1]
        gi = self.op(
            "Gemm",
            [
                f,
                self.const(f"{prefix}.w_ih_t", sd[f"{prefix}.weight_ih_l0"].T),
                self.const(f"{prefix}.b_ih", sd[f"{prefix}.bias_ih_l0"]),
            ],
        )
        gh = self.op(
            "Gemm",
            [
                h,
                self.const(f"{prefix}.w_hh_t", sd[f"{prefix}.weight_hh_l0"].T),
                self.const(f"{prefix}.b_hh", sd[f"{prefix}.bias_hh_l0"]),
            ],
        )
        ir, iu, i_n = self.split3(gi, H)
        hr, hu, h_n = self.split3(gh, H)
        r = self.op("Sigmoid", [self.op("Add", [ir, hr])])
        u = self.op("Sigmoid", [self.op("Add", [iu, hu])])
        n = self.op("Tanh", [self.op("Add", [i_n, self.op("Mul", [r, h_n])])])
        return self.op("Add", [n, self.op("Mul", [u, self.op("Sub", [h, n])])], out=out)

    def normalise(self, x: str, mean: np.ndarray, std: np.ndarray, prefix: str) -> str:
        centred = self.op("Sub", [x, self.const(f"{prefix}.mean", mean)])
        return self.op("Mul", [centred, self.const(f"{prefix}.inv_std", 1.0 / std)])

    def model(self, name: str, inputs: dict[str, int], outputs: dict[str, int]) -> onnx.ModelProto:
        def vi(n: str, width: int) -> onnx.ValueInfoProto:
            return helper.make_tensor_value_info(n, TensorProto.FLOAT, ["B", width])

        graph = helper.make_graph(
            self.nodes,
            name,
            [vi(k, v) for k, v in inputs.items()],
            [vi(k, v) for k, v in outputs.items()],
            self.inits,
        )
        m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
        m.ir_version = 8
        m.producer_name = f"posecast {__version__}"
        onnx.checker.check_model(m)
        return m


def _state(ckpt: dict[str, Any]) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy() for k, v in ckpt["model"].items()}


def _decoder_nodes(
    g: _Graph, sd: dict[str, np.ndarray], x: str, z: str, h: str, h_out: str, n_feat: int
) -> None:
    w = sd["decoder.fc.weight"]  # (128, 54): tracker columns first, then latent
    fx = g.op(
        "Gemm",
        [
            x,
            g.const("decoder.fc.wx_t", w[:, :n_feat].T),
            g.const("decoder.fc.bias", sd["decoder.fc.bias"]),
        ],
    )
    fz = g.op("MatMul", [z, g.const("decoder.fc.wz_t", w[:, n_feat:].T)])
    f = g.op("Relu", [g.op("Add", [fx, fz])])
    h_new = g.gru_step(f, h, sd, "decoder.gru", out=h_out)
    a = g.op("Relu", [h_new])
    n_out = sd["decoder.pose.weight"].shape[0]
    g.op("Identity", [g.linear(a, sd, "decoder.pose", slice(0, 108))], out="rotations")
    if n_out > 108:  # the headset-only model's pelvis outputs
        g.op("Identity", [g.linear(a, sd, "decoder.pose", slice(108, n_out))], out="root")
    g.op("Sigmoid", [g.linear(a, sd, "decoder.contact")], out="contacts")


def build_decoder(ckpt: dict[str, Any]) -> onnx.ModelProto:
    sd, norm = _state(ckpt), ckpt["norm"]
    n_feat = int(ckpt["config"].get("n_features", len(FEATURE_NAMES)))
    g = _Graph()
    x = g.normalise("features", np.asarray(norm["feat_mean"]), np.asarray(norm["feat_std"]), "feat")
    _decoder_nodes(g, sd, x, "z", "h", "h_out", n_feat)
    hidden = sd["decoder.gru.weight_hh_l0"].shape[1]
    latent = sd["decoder.fc.weight"].shape[1] - n_feat
    root = sd["decoder.pose.weight"].shape[0] - 108
    return g.model(
        "posecast_cvae_decoder_step",
        {"features": n_feat, "z": latent, "h": hidden},
        {"rotations": 108} | ({"root": root} if root else {}) | {"contacts": 2, "h_out": hidden},
    )


def build_ae_step(ckpt: dict[str, Any]) -> onnx.ModelProto:
    sd, norm = _state(ckpt), ckpt["norm"]
    g = _Graph()
    x = g.normalise("features", np.asarray(norm["feat_mean"]), np.asarray(norm["feat_std"]), "feat")
    fe = g.op("Relu", [g.linear(x, sd, "encoder.fc")])
    h_enc = g.gru_step(fe, "h_enc", sd, "encoder.gru", out="h_enc_out")
    z = g.linear(h_enc, sd, "encoder.z")
    _decoder_nodes(g, sd, x, z, "h_dec", "h_dec_out", len(FEATURE_NAMES))
    hidden = sd["decoder.gru.weight_hh_l0"].shape[1]
    return g.model(
        "posecast_ae_step",
        {"features": len(FEATURE_NAMES), "h_enc": hidden, "h_dec": hidden},
        {"rotations": 108, "contacts": 2, "h_enc_out": hidden, "h_dec_out": hidden},
    )


def build_anomaly(ckpt: dict[str, Any]) -> onnx.ModelProto:
    sd, norm = _state(ckpt), ckpt["norm"]
    g = _Graph()
    x = g.normalise(
        "local_positions", np.asarray(norm["pose_mean"]), np.asarray(norm["pose_std"]), "pose"
    )
    n_layers = len(ckpt["config"]["widths"]) - 1
    for i in range(n_layers):
        x = g.linear(x, sd, f"layers.{i}")
        if i < n_layers - 1:
            x = g.op("Relu", [x])
    g.op("Identity", [x], out="rotations")
    return g.model("posecast_anomaly_ae", {"local_positions": 57}, {"rotations": 108})


def git_revision(cwd: str | Path | None = None) -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, check=True
        )
        # Dirty: a tracked file changed, the artifacts being written aside (an export
        # that replaces a shipped model would otherwise always call itself dirty).
        dirty = subprocess.run(
            [
                "git",
                "status",
                "--porcelain",
                "--untracked-files=no",
                "--",
                ":/",
                ":(top,exclude)server/posecast/artifacts",
            ],
            cwd=cwd,
            capture_output=True,
            text=True,
            check=True,
        )
        return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def sidecar(
    ckpt: dict[str, Any], kind: str, model: onnx.ModelProto, **extra: Any
) -> dict[str, Any]:
    """Everything the server needs to use an artifact without flags or the training code."""
    splits = ckpt.get("data", {}).get("splits", {})
    ls = spec(ckpt.get("config", {}).get("layout", Layout.HMD3_WAIST))
    return {
        "format": ARTIFACT_FORMAT,
        "version": ARTIFACT_VERSION,
        "kind": kind,
        "inputs": {
            i.name: [d.dim_param or d.dim_value for d in i.type.tensor_type.shape.dim]
            for i in model.graph.input
        },
        "outputs": {
            o.name: [d.dim_param or d.dim_value for d in o.type.tensor_type.shape.dim]
            for o in model.graph.output
        },
        "fps": 60.0,
        "joint_order": list(JOINT_NAMES),
        "rotation_joints": list(JOINT_NAMES[1:]),
        "rotation_layout": "6D per joint: first two columns of the local rotation matrix, [c0, c1]",
        "parents": list(PARENTS),
        "skeleton_offsets_m": reference_offsets().round(6).tolist(),
        "layout": str(ls.layout),
        "tracker_slots": (
            {s.value: SITE_JOINT[s].name for s in SITES}
            if ls.layout is Layout.SITES
            else {s.name: TRACKER_JOINT[s].name for s in ls.slots}
        ),
        "feature_layout": list(ls.feature_names),
        "normalisation": ckpt["norm"],
        "model_config": ckpt["config"],
        "training": {
            "config": ckpt.get("train_config", {}),
            "steps": ckpt.get("step"),
            "train_seconds": round(float(ckpt.get("train_seconds", 0.0)), 1),
            "train_frames_after_augmentation": ckpt.get("train_frames"),
            "final_log": (ckpt.get("history") or [{}])[-1],
        },
        "data_hours": {k: v.get("hours") for k, v in splits.items()},
        "data_credit": "The data used in this project was obtained from mocap.cs.cmu.edu. "
        "The database was created with funding from NSF EIA-0196217.",
        "git_revision": git_revision(Path(__file__).parent),
        "posecast_version": __version__,
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
    } | extra


def mean_pose_rot6d(data_dir: str | Path) -> list[float]:
    """Mean local rotation of each joint over the training split, mirrored for symmetry.

    The 6D vectors are averaged and re-orthonormalised; the evaluation's
    ``baseline_mean_lower_body`` stands its legs in this pose.
    """
    from posecast.geometry.rotations import mat2r6d, r6d2mat
    from posecast.offline.dataset.augment import Augmentation
    from posecast.offline.dataset.store import load_split
    from posecast.offline.train.data import build_arrays

    arr = build_arrays(load_split(data_dir, "train"), Augmentation(mirror=True))
    mean = arr.rot6d.astype(np.float64).mean(axis=0)  # (18, 6)
    return [float(v) for v in mat2r6d(r6d2mat(mean)).reshape(-1)]


def export_all(
    out_dir: str | Path,
    cvae: str | Path | None = None,
    ae: str | Path | None = None,
    anomaly: str | Path | None = None,
    extra: dict[str, dict[str, Any]] | None = None,
    cvae_hmd3: str | Path | None = None,
    cvae_sites: str | Path | None = None,
) -> list[Path]:
    """Write the ONNX files and sidecars for whichever checkpoints are given."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    jobs = [
        ("cvae_decoder", cvae, build_decoder),
        ("cvae_decoder_hmd3", cvae_hmd3, build_decoder),
        ("cvae_decoder_sites", cvae_sites, build_decoder),
        ("ae_step", ae, build_ae_step),
        ("anomaly", anomaly, build_anomaly),
    ]
    for name, path, build in jobs:
        if path is None:
            continue
        ckpt = load_checkpoint(path)
        model = build(ckpt)
        more = dict((extra or {}).get(name, {}))
        if name == "anomaly" and "val_error_p99_m" in ckpt:
            more["implausible_threshold_m"] = ckpt["val_error_p99_m"]
            more["val_error_mean_m"] = ckpt.get("val_error_mean_m")
        onnx.save(model, out / f"{name}.onnx")
        meta = sidecar(ckpt, name, model, **more)
        (out / f"{name}.json").write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
        written += [out / f"{name}.onnx", out / f"{name}.json"]
    return written
