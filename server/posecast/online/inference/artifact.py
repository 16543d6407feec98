"""Load a shipped model: the ONNX graph plus its JSON sidecar, validated against this code.

The server and the evaluator rebuild everything from the artifact (normalisation,
joint order, feature layout, thresholds), never from flags. A sidecar whose joint
order or feature layout differs from this code's is refused: a silent mismatch would
animate the wrong joints.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from posecast.errors import ModelError
from posecast.skeleton import JOINT_NAMES
from posecast.tracking.layouts import Layout, spec

ARTIFACT_FORMAT = "posecast-model"
ARTIFACT_VERSION = 1


def default_models_dir() -> Path:
    return Path(str(resources.files("posecast") / "artifacts"))


def session_options(threads: int = 1) -> ort.SessionOptions:
    """Deliberate threading: ``threads`` intra-op threads, no inter-op pool, no spinning."""
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return so


@dataclass
class Artifact:
    name: str
    meta: dict[str, Any]
    session: ort.InferenceSession

    def run(self, **inputs: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = self.session.run(None, inputs)
        return out

    def run_into(self, inputs: dict[str, np.ndarray], outputs: dict[str, np.ndarray]) -> None:
        """Run with every output written into the given float32 C-contiguous arrays.

        No output is allocated or copied: ONNX Runtime writes straight into the
        caller's buffers (the engine's ring rows).
        """
        binding = self.session.io_binding()
        for name, arr in inputs.items():
            binding.bind_cpu_input(name, np.ascontiguousarray(arr, dtype=np.float32))
        for name, arr in outputs.items():
            if arr.dtype != np.float32 or not arr.flags.c_contiguous:
                raise ValueError(f"output {name} must be float32 and C-contiguous")
            binding.bind_output(name, "cpu", 0, np.float32, list(arr.shape), arr.ctypes.data)
        self.session.run_with_iobinding(binding)

    @property
    def output_names(self) -> list[str]:
        return [o.name for o in self.session.get_outputs()]


def read_sidecar(name: str, models_dir: str | Path | None = None) -> tuple[dict[str, Any], Path]:
    """The validated sidecar of ``<models_dir>/<name>`` and the path of its ONNX file.

    Every backend reads its model through here, so all of them refuse the same
    mismatches (joint order, tracker layout, feature layout).
    """
    folder = Path(models_dir) if models_dir is not None else default_models_dir()
    onnx_path, meta_path = folder / f"{name}.onnx", folder / f"{name}.json"
    try:
        meta = json.loads(meta_path.read_text("utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(f"cannot read sidecar: {exc}", path=meta_path) from exc
    if meta.get("format") != ARTIFACT_FORMAT or meta.get("version") != ARTIFACT_VERSION:
        raise ModelError(f"not a {ARTIFACT_FORMAT} v{ARTIFACT_VERSION} sidecar", path=meta_path)
    if meta.get("joint_order") != list(JOINT_NAMES):
        raise ModelError("sidecar joint order differs from this posecast", path=meta_path)
    try:
        layout = spec(meta.get("layout", Layout.HMD3_WAIST))
    except ValueError:
        raise ModelError(f"unknown tracker layout {meta.get('layout')!r}", path=meta_path) from None
    if meta.get("feature_layout") != list(layout.feature_names):
        raise ModelError("sidecar feature layout differs from this posecast", path=meta_path)
    return meta, onnx_path


def load_artifact(name: str, models_dir: str | Path | None = None, threads: int = 1) -> Artifact:
    """Load ``<models_dir>/<name>.onnx`` and ``<name>.json`` (default: the shipped models)."""
    meta, onnx_path = read_sidecar(name, models_dir)
    try:
        session = ort.InferenceSession(
            str(onnx_path), session_options(threads), providers=["CPUExecutionProvider"]
        )
    except Exception as exc:  # onnxruntime raises its own unexported exception types
        raise ModelError(f"cannot load ONNX model: {exc}", path=onnx_path) from exc
    return Artifact(name, meta, session)
