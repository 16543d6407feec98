"""Shipped artifacts load with ONNX Runtime alone and refuse to load when they don't fit."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from posecast.errors import ModelError
from posecast.online.inference.artifact import default_models_dir, load_artifact
from posecast.skeleton import JOINT_NAMES
from posecast.tracking.features import FEATURE_NAMES

NAMES = ("cvae_decoder", "ae_step", "anomaly")


@pytest.mark.parametrize("name", NAMES)
def test_shipped_sidecar_describes_its_model(name: str) -> None:
    art = load_artifact(name)
    meta = art.meta
    assert meta["joint_order"] == list(JOINT_NAMES)
    assert meta["feature_layout"] == list(FEATURE_NAMES)
    assert [i.name for i in art.session.get_inputs()] == list(meta["inputs"])
    assert art.output_names == list(meta["outputs"])
    for key in ("normalisation", "skeleton_offsets_m", "training", "data_hours", "git_revision"):
        assert key in meta, key
    assert "mocap.cs.cmu.edu" in meta["data_credit"]


def test_anomaly_sidecar_has_a_threshold() -> None:
    assert load_artifact("anomaly").meta["implausible_threshold_m"] > 0


def test_decoder_runs() -> None:
    dec = load_artifact("cvae_decoder")
    rng = np.random.default_rng(0)
    rot, con, h = dec.run(
        features=rng.normal(size=(3, 24)).astype(np.float32),
        z=rng.normal(size=(3, 30)).astype(np.float32),
        h=np.zeros((3, 128), np.float32),
    )
    assert rot.shape == (3, 108) and con.shape == (3, 2) and h.shape == (3, 128)
    assert np.all((con >= 0) & (con <= 1))


def test_weights_load_without_torch() -> None:
    """A serving install has no torch: block its import and run the engine."""
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "import numpy as np\n"
        "from posecast.online.engine.types import TrackerFrame\n"
        "from posecast.online.inference.loader import load_engine\n"
        "e = load_engine(); e.add_player('a', seed=0)\n"
        "pos = np.tile([[0.0, 1.6, 0.0]], (4, 1)); q = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))\n"
        "for t in range(12): e.push('a', TrackerFrame(t, pos, q)); r = e.tick()\n"
        "assert len(r.poses) == 1 and 'torch' not in [m for m in sys.modules if sys.modules[m]]\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def _copy_models(tmp_path: Path) -> Path:
    dst = tmp_path / "models"
    shutil.copytree(default_models_dir(), dst)
    return dst


def test_wrong_joint_order_is_refused(tmp_path: Path) -> None:
    models = _copy_models(tmp_path)
    meta_path = models / "cvae_decoder.json"
    meta = json.loads(meta_path.read_text())
    meta["joint_order"] = list(reversed(meta["joint_order"]))
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(ModelError, match="joint order"):
        load_artifact("cvae_decoder", models)


def test_missing_and_corrupt_artifacts_are_refused(tmp_path: Path) -> None:
    models = _copy_models(tmp_path)
    with pytest.raises(ModelError):
        load_artifact("nonexistent", models)
    (models / "anomaly.onnx").write_bytes(b"not onnx")
    with pytest.raises(ModelError, match="ONNX"):
        load_artifact("anomaly", models)
    (models / "ae_step.json").write_text('{"format": "other"}')
    with pytest.raises(ModelError):
        load_artifact("ae_step", models)
