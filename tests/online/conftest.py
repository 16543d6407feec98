"""Fixtures for the service tests: a config, tokens, frames, and (for the end-to-end
tests) a real server on an ephemeral loopback port with the shipped ONNX models.

The models are loaded once per test session, on the ``onnx`` backend (the engine tests
run every backend); each server builds its own small engine on them (``samples=8``)
so a test's server starts in milliseconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np
import pytest

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.auth.keys import SigningKey
from posecast.online.auth.tokens import mint
from posecast.online.config import ServerConfig
from posecast.online.engine.ssi import Engine
from posecast.online.inference.auto import Backend, load_backend
from posecast.online.protocol.messages import Frame

SECRET = "test-secret-" + "x" * 20


def make_cfg(**changes: Any) -> ServerConfig:
    """Test defaults: ephemeral port, 8 samples, generous per-IP limits (every test
    client comes from loopback; test_hostile_churn and test_transport_edge test the
    limits themselves)."""
    base: dict[str, Any] = {
        "token_secret": SECRET,
        "port": 0,
        "samples": 8,
        "conn_per_ip_per_min": 10_000,
        "sockets_per_ip": 10_000,
        "fatal_per_ip_per_min": 10_000,
        "accepts_per_s": 10_000.0,
    }
    base.update(changes)
    return ServerConfig(**base)


def token(
    room: str = "r1", player: str = "p1", role: str = "player", ttl_s: int = 600, **kw: Any
) -> str:
    return mint(
        SigningKey.from_secret(SECRET),
        room=room,
        player=player,
        role=role,
        ttl_s=ttl_s,
        now=time.time(),
        **kw,
    )


@cache
def _walk(seed: int) -> tuple[np.ndarray, np.ndarray]:
    w = derive_frames(walk_clip(seconds=4.0, fps=60.0, seed=seed))
    return w["tracker_pos"].astype(np.float64), w["tracker_quat"].astype(np.float64)


def walk_frame(seq: int, seed: int = 0, t: float | None = None) -> Frame:
    """Frame ``seq`` of a 4 s walk (looped), as a wire message."""
    pos, quat = _walk(seed)
    i = seq % len(pos)
    return Frame(seq, time.time() if t is None else t, pos[i], quat[i])


@pytest.fixture(scope="session")
def onnx_backend() -> Backend:
    return load_backend("onnx")


@pytest.fixture(scope="session")
def engine_factory(onnx_backend: Backend) -> Callable[[ServerConfig], Callable[[], Engine]]:
    """``engine_factory(cfg)``: builds that config's engine on the shared models."""
    dec, pool = onnx_backend.decoder, onnx_backend.pool

    def for_cfg(cfg: ServerConfig) -> Callable[[], Engine]:
        ecfg = cfg.engine_config()
        return lambda: Engine(dec, pool, ecfg, backend_name=onnx_backend.name)

    return for_cfg
