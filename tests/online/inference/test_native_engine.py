"""The whole engine on the native backend against the onnx reference, over a 60 s clip.

Issue 18's bar for the fp32 levels: the same samples chosen (so the same transitions)
and the same poses emitted as the ``onnx`` backend, within 1 mm, for every player and
frame of 60 s of walking, on both layouts, on every fp32 level this CPU runs, with
transitions (so the re-decoded interpolated latents are compared too).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

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


@dataclass
class Run:
    keys: list[tuple[str, int, int]]  # (player, seq, shown sample) of every pose
    poses: np.ndarray  # (poses, 19, 3)
    transitions: list[int]  # transitions started at each tick
    scores: list[np.ndarray]  # each tick's anomaly scores (P, N), the decisions' input
    current: list[list[int]]  # each player's current sample before each tick's decision


def _run(backend: str, layout: Layout) -> Run:
    # outlier factor 1 (default 2): the walk then needs transitions, about 3 a second
    cfg = EngineConfig(samples=SAMPLES, outlier_factor=1.0)
    engine = load_engine(cfg, layout=layout, backend=backend)
    assert engine.backend_name == backend
    for p in range(PLAYERS):
        engine.add_player(f"p{p}", seed=10 + p)
    clips = [_clip(p) for p in range(PLAYERS)]
    run = Run([], np.empty(0), [], [], [])
    step = engine.pool.step
    poses: list[np.ndarray] = []

    def recording_step(*args: Any, **kw: Any) -> Any:
        out = step(*args, **kw)
        run.scores.append(np.array(out, np.float64).reshape(PLAYERS, SAMPLES))
        return out

    engine.pool.step = recording_step  # type: ignore[method-assign]
    for t in range(len(clips[0][0])):
        for p, (pos, quat) in enumerate(clips):
            engine.push(f"p{p}", TrackerFrame(t, pos[t], quat[t]))
        run.current.append([engine.players[f"p{p}"].current for p in range(PLAYERS)])
        result = engine.tick()
        run.transitions.append(result.transitions)
        for pose in result.poses:
            run.keys.append((pose.player, pose.seq, pose.sample))
            poses.append(pose.positions)
    run.poses = np.asarray(poses)
    return run


@pytest.fixture(scope="module")
def reference() -> dict[Layout, Run]:
    return {layout: _run("onnx", layout) for layout in (Layout.HMD3_WAIST, Layout.HMD3)}


@pytest.mark.slow
@pytest.mark.parametrize("layout", [Layout.HMD3_WAIST, Layout.HMD3])
@pytest.mark.parametrize("level", [lv for lv in native.native_isas() if lv != "avx512bf16"])
def test_native_emits_the_onnx_samples_and_poses_within_1mm(
    reference: dict[Layout, Run], layout: Layout, level: str
) -> None:
    """The same anomaly scores, samples and poses as ``onnx`` up to the first tick at
    which the two backends decide differently, which must not come early.

    The engine has discrete thresholds fed with values the backends compute in float32
    in different orders (about 1e-6 apart): the selector's comparisons of scores, and
    each sample's contact IK (a contact probability against 0.5, a lock's drift against
    ``ik_max_drift_m``). Now and then a value falls that close to its threshold; from
    there that sample's foot lock (and so its score, by millimetres) or the shown sample
    rightly differ. So: at most 1 % of the score entries before the split may differ by
    more than 1e-4 (their median difference stays under 1e-5), at most 1 % of the poses
    by more than 1 mm, and the split may not come before a quarter of the clip with at
    least 50 transitions. A kernel bug shows everywhere, and from the start."""
    before = native.native_isa()
    native.set_native_isa(level)
    try:
        got = _run("native", layout)
    finally:
        native.set_native_isa(before)
    ref = reference[layout]
    assert len(got.keys) == len(ref.keys) > 3000 * PLAYERS
    ticks = len(ref.transitions)
    split = next((t for t in range(ticks) if got.transitions[t] != ref.transitions[t]), ticks)
    assert split >= ticks // 4 and sum(ref.transitions[:split]) > 50, f"split at tick {split}"
    diff = np.concatenate(
        [np.abs(g - r).ravel() for g, r in zip(got.scores[:split], ref.scores[:split], strict=True)]
    )
    assert np.median(diff) < 1e-5 and np.mean(diff > 1e-4) <= 0.01, (
        np.median(diff),
        np.mean(diff > 1e-4),
    )
    # Poses: every one made before the split (look-ahead: seq < split - lookahead).
    cut = max(0, split - EngineConfig().delay - 1)
    shown = [i for i, k in enumerate(ref.keys) if k[1] < cut]
    assert [got.keys[i] for i in shown] == [ref.keys[i] for i in shown], "a different sample"
    err = np.linalg.norm(got.poses[shown] - ref.poses[shown], axis=-1).max(axis=-1)
    assert np.mean(err > 1e-3) <= 0.01, f"{np.mean(err > 1e-3):.2%} of poses over 1 mm"
    print(
        f"{level} {layout}: split at tick {split} of {ticks}, {len(shown)} poses compared, "
        f"{np.mean(diff > 1e-4):.2%} of scores and {np.mean(err > 1e-3):.2%} of poses apart"
    )
