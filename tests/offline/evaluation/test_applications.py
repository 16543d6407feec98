"""Table 3 machinery on a generated clip: targets, obstacle and the report's shape."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.evaluation.applications import kick_targets, table3
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.inference.auto import load_backend
from posecast.skeleton import Joint


@pytest.fixture(scope="module")
def clip() -> dict[str, np.ndarray]:
    return derive_frames(walk_clip(1.5, 60.0, seed=4))


def test_targets_sit_at_the_apex_in_front(clip: dict[str, np.ndarray]) -> None:
    apex, targets = kick_targets(clip, Joint.RIGHT_FOOT)
    assert apex == int(np.argmax(clip["positions"][:, Joint.RIGHT_FOOT, 1]))
    assert targets["low"][1] == pytest.approx(0.45)
    assert targets["high"][1] == pytest.approx(1.05)


def test_report_has_every_count_and_task(clip: dict[str, np.ndarray]) -> None:
    rep = table3(load_backend("onnx"), clip, sample_counts=(1, 4), runs=3)
    assert rep["backend"] == "onnx"
    assert set(rep["samples"]) == {"1", "4"}
    for row in rep["samples"].values():
        for task in ("low_kick_m", "high_kick_m", "collision_share"):
            assert np.isfinite(row[task]["mean"]) and row[task]["std"] >= 0
        assert 0.0 <= row["collision_share"]["mean"] <= 1.0
    # One sample per run, drawn at random per run: the runs differ.
    assert rep["samples"]["1"]["low_kick_m"]["std"] > 0
    assert 0.0 <= rep["ground_truth_collision_share"] <= 1.0
