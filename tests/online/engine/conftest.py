"""Fixtures for the engine tests: the shipped models (loaded once) and walk trackers.

The ONNX sessions are session-scoped, so every engine test shares one decoder and one
anomaly autoencoder. The models are early-training weights that later releases
replace with the same interface, so no test here relies on how good they are beyond
what any trained model gives (see each test's docstring).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np
import pytest

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.anomaly import AnomalyScorer
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.artifact import Artifact, load_artifact

FPS = 60.0
WALK_SECONDS = 1.5  # 90 frames: walking, a pause in the middle fifth, walking again


@pytest.fixture(scope="session")
def decoder() -> Artifact:
    return load_artifact("cvae_decoder")


@pytest.fixture(scope="session")
def anomaly_artifact() -> Artifact:
    return load_artifact("anomaly")


@pytest.fixture(scope="session")
def scorer(anomaly_artifact: Artifact) -> AnomalyScorer:
    return AnomalyScorer(anomaly_artifact)


@cache
def _walk(seed: int) -> dict[str, np.ndarray]:
    frames = derive_frames(walk_clip(seconds=WALK_SECONDS, fps=FPS, seed=seed))
    return {k: v.astype(np.float64) for k, v in frames.items()}


@pytest.fixture(scope="session")
def walk_arrays() -> Callable[[int], dict[str, np.ndarray]]:
    """``walk_arrays(seed)``: :func:`derive_frames` of a 1.5 s walk, as float64 arrays.

    Fields of interest: ``tracker_pos (90, 4, 3)``, ``tracker_quat (90, 4, 4)``,
    ``positions (90, 19, 3)`` (ground truth), ``contacts (90, 2)``.
    """
    return _walk


@pytest.fixture(scope="session")
def walk_frames() -> Callable[..., list[TrackerFrame]]:
    """``walk_frames(seed, seq0=0)``: the walk of ``seed`` as tracker frames, seq from ``seq0``."""

    def make(seed: int, seq0: int = 0) -> list[TrackerFrame]:
        w = _walk(seed)
        return [
            TrackerFrame(seq0 + i, pos, quat)
            for i, (pos, quat) in enumerate(zip(w["tracker_pos"], w["tracker_quat"], strict=True))
        ]

    return make


@pytest.fixture(scope="session")
def make_engine(decoder: Artifact, scorer: AnomalyScorer) -> Callable[..., Engine]:
    """``make_engine(anomaly=None, capacity=8, **EngineConfig fields)``: a fresh engine on
    the shared models (``anomaly`` replaces the shared scorer). Tests pass small
    ``samples`` (10 or 20) to stay fast."""

    def make(*, anomaly: AnomalyScorer | None = None, capacity: int = 8, **cfg: Any) -> Engine:
        return Engine(decoder, anomaly or scorer, EngineConfig(**cfg), capacity=capacity)

    return make
