"""Fixtures shared by the whole suite: a seeded generator, a walking clip, BVH files."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh

# The native kernels' default precision is bf16 on a CPU with avx512_bf16 and fp32
# elsewhere. The suite's parity and golden tests are written for fp32, so they run in
# fp32 on every machine (before posecast._native is first imported, here or in a
# server the tests start); the bf16 precision has tests of its own that set it
# (tests/online/inference/test_native_bf16.py, the default in a clean environment).
os.environ.setdefault("POSECAST_NATIVE_PRECISION", "fp32")


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh generator with a fixed seed, so every test sees the same numbers."""
    return np.random.default_rng(20240611)


@pytest.fixture
def walk() -> CanonicalClip:
    """Two seconds of the procedural walk at 60 fps (120 frames, feet on the floor)."""
    return walk_clip(seconds=2.0, fps=60.0, seed=0)


@pytest.fixture
def fixture_bvh(tmp_path: Path) -> Callable[..., Path]:
    """Factory: ``fixture_bvh(clip, layout="posecast", gz=False)`` writes a BVH file.

    ``layout`` is a built-in rig name (``posecast``, ``cmu_mb``, ``cmu_daz``); see
    :func:`posecast.offline.motion.synthetic.write_fixture_bvh`.
    """

    def make(clip: CanonicalClip, layout: str = "posecast", *, gz: bool = False) -> Path:
        path = tmp_path / f"{clip.name}_{layout}.bvh{'.gz' if gz else ''}"
        write_fixture_bvh(path, clip, layout)
        return path

    return make
