"""The whole engine on the native backend against the onnx reference, over a 60 s clip.

Issue 18's bar for the fp32 levels: the same samples chosen (so the same transitions)
and the same poses emitted as the ``onnx`` backend, within 1 mm, for every player and
frame of 60 s of walking, on both layouts, on every fp32 level this CPU runs, with
transitions (so the re-decoded interpolated latents are compared too).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine
from posecast.tracking.layouts import Layout

native = pytest.importorskip("posecast.online.inference.native")

SECONDS, PLAYERS, SAMPLES = 60.0, 2, 32


@cache
def _clip(seed: int) -> tuple[np.ndarray, np.ndarray]:
    w = derive_frames(walk_clip(seconds=SECONDS, fps=60.0, seed=seed))
    return w["tracker_pos"].astype(np.float64), w["tracker_quat"].astype(np.float64)


def _run(backend: str, layout: Layout) -> tuple[list[tuple[str, int, int]], np.ndarray, list[int]]:
    # outlier factor 1 (default 2): the walk then needs transitions, about 3 a second
    cfg = EngineConfig(samples=SAMPLES, outlier_factor=1.0)
    engine = load_engine(cfg, layout=layout, backend=backend)
    assert engine.backend_name == backend
    for p in range(PLAYERS):
        engine.add_player(f"p{p}", seed=10 + p)
    clips = [_clip(p) for p in range(PLAYERS)]
    keys: list[tuple[str, int, int]] = []
    poses: list[np.ndarray] = []
    transitions: list[int] = []  # the running count, at each emitted pose
    count = 0
    for t in range(len(clips[0][0])):
        for p, (pos, quat) in enumerate(clips):
            engine.push(f"p{p}", TrackerFrame(t, pos[t], quat[t]))
        result = engine.tick()
        count += result.transitions
        for pose in result.poses:
            keys.append((pose.player, pose.seq, pose.sample))
            poses.append(pose.positions)
            transitions.append(count)
    return keys, np.asarray(poses), transitions


@pytest.fixture(scope="module")
def reference() -> dict[Layout, tuple[list[tuple[str, int, int]], np.ndarray, list[int]]]:
    return {layout: _run("onnx", layout) for layout in (Layout.HMD3_WAIST, Layout.HMD3)}


@pytest.mark.slow
@pytest.mark.parametrize("layout", [Layout.HMD3_WAIST, Layout.HMD3])
@pytest.mark.parametrize("level", [lv for lv in native.native_isas() if lv != "avx512bf16"])
def test_native_emits_the_onnx_samples_and_poses_within_1mm(
    reference: dict[Layout, tuple[list[tuple[str, int, int]], np.ndarray, list[int]]],
    layout: Layout,
    level: str,
) -> None:
    """The same samples shown and every pose within 1 mm, up to the first decision the
    two backends take differently, which must not come before 60 % of the clip.

    A selector decision is a comparison of anomaly scores the backends compute in float32
    in different orders (about 1e-6 apart); over 550 transitions a comparison that close
    to a tie can come up, and from there the two engines rightly go separate ways (one
    did, at 64 % of the clip, for ``hmd3`` on ``avx2`` when the contact IK's defaults
    changed). A kernel bug shows from the start."""
    before = native.native_isa()
    native.set_native_isa(level)
    try:
        keys, poses, transitions = _run("native", layout)
    finally:
        native.set_native_isa(before)
    ref_keys, ref_poses, ref_transitions = reference[layout]
    assert len(keys) == len(ref_keys) > 3000 * PLAYERS
    # A decision shows first in the transition count, the shown sample's label a few
    # poses later (look-ahead): the first pose where either differs.
    same = [
        a == b and n == m
        for a, b, n, m in zip(keys, ref_keys, transitions, ref_transitions, strict=True)
    ]
    agree = same.index(False) if False in same else len(same)
    assert agree >= 0.6 * len(same), f"the backends decided differently at pose {agree}"
    assert ref_transitions[agree - 1] > 50
    err = np.linalg.norm(poses[:agree] - ref_poses[:agree], axis=-1)
    assert err.max() < 1e-3, f"max {err.max() * 1000:.3f} mm"
