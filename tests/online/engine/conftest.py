"""Fixtures for the engine tests: every backend, the shipped models (loaded once) and
walk trackers.

``backend`` is parametrised over every backend this install can run (``onnx`` always,
``torch`` where torch is installed, ``native`` where ``posecast._native`` imports), so
every test that builds an engine through it (``make_engine`` does) runs once per
backend. Models are loaded once per backend and session. They are early-training
weights that later releases replace with the same interface, so no test here relies
on how good they are beyond what any trained model gives (see each test's docstring).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ports import Pool, StepDecoder
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import PoseOut, TrackerFrame
from posecast.online.inference.anomaly import AnomalyScorer
from posecast.online.inference.artifact import Artifact, load_artifact
from posecast.online.inference.auto import Backend, load_backend
from posecast.tracking.layouts import Layout

FPS = 60.0
WALK_SECONDS = 1.5  # 90 frames: walking, a pause in the middle fifth, walking again


def available_backends() -> list[str]:
    names = ["onnx"]
    if importlib.util.find_spec("torch") and importlib.util.find_spec("onnx"):
        names.append("torch")
    try:
        import posecast._native  # type: ignore[import-not-found]  # noqa: F401
    except ImportError:
        pass
    else:
        names.append("native")
    return names


class BackendLoader:
    """``backend(layout, models_dir=None, cfg=None)``: the backend ``name`` on a layout's
    models, loaded once per layout, folder and contact-IK settings (the pool's)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._loaded: dict[tuple[str, str, int, float | None], Backend] = {}

    def __call__(
        self,
        layout: str = Layout.HMD3_WAIST,
        models_dir: Path | None = None,
        cfg: EngineConfig | None = None,
    ) -> Backend:
        cfg = cfg or EngineConfig()
        key = (str(layout), str(models_dir), cfg.ik_release_frames, cfg.ik_max_drift_m)
        if key not in self._loaded:
            b = load_backend(self.name, layout, models_dir, threads=1, cfg=cfg)
            assert b.name == self.name, f"{self.name} fell back to {b.name}"
            self._loaded[key] = b
        return self._loaded[key]

    def engine(
        self,
        layout: str = Layout.HMD3_WAIST,
        models_dir: Path | None = None,
        *,
        decoder: StepDecoder | None = None,
        pool: Pool | None = None,
        capacity: int = 8,
        **cfg: Any,
    ) -> Engine:
        """A fresh engine on this backend (``decoder``, ``pool`` replace the backend's)."""
        ecfg = EngineConfig(**cfg)
        b = self(layout, models_dir, ecfg)
        return Engine(decoder or b.decoder, pool or b.pool, ecfg, capacity, backend_name=b.name)


@pytest.fixture(scope="session", params=available_backends())
def backend(request: pytest.FixtureRequest) -> BackendLoader:
    """Every backend in turn (see the module docstring)."""
    return BackendLoader(request.param)


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
def make_engine(backend: BackendLoader) -> Callable[..., Engine]:
    """``make_engine(decoder=None, pool=None, capacity=8, **EngineConfig fields)``: a fresh
    4-point engine on the shared models of each backend (``decoder``, ``pool`` replace
    the backend's).
    Tests pass small ``samples`` (10 or 20) to stay fast."""
    return backend.engine


def run_player(engine: Engine, frames: list[TrackerFrame], seed: int = 3) -> list[PoseOut]:
    """Join one player ``p`` (latents from ``seed``) and stream ``frames``, a tick each:
    every pose the engine emits, in order."""
    engine.add_player("p", seed=seed)
    out: list[PoseOut] = []
    for f in frames:
        engine.push("p", f)
        out += engine.tick().poses
    return out
