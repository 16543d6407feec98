"""Presence: by default every pose is the newest frame's; the paper's delayed emission
is one option away; a player may ask for its poses forecast ahead (docs/latency.md)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from posecast.body.forecast import forecast
from posecast.online.engine.forecasting import HISTORY
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import PoseOut, TrackerFrame
from posecast.skeleton import Joint
from tests.online.engine.test_ssi import Forced, Never, run

MakeEngine = Callable[..., Engine]
WalkFrames = Callable[..., list[TrackerFrame]]


def test_every_tick_emits_the_newest_frame_with_head_and_hands_on_it(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """Default engine: the pose emitted at tick ``n`` is frame ``n``'s (its ``seq``),
    one per frame from the first tick, with the head and hands on that frame's
    trackers (the upper-body pass), and transitions still run."""
    frames = walk_frames(0)
    engine = make_engine(samples=10)
    engine.add_player("a", seed=1, selector=Forced(at=31, to=4))
    for t, frame in enumerate(frames):
        engine.push("a", frame)
        (pose,) = engine.tick().poses
        assert pose.seq == frame.seq == t and pose.ahead_ms == 0.0
        head = pose.positions[int(Joint.HEAD)]
        assert np.linalg.norm(head - frame.pos[0]) < 0.03, t  # the head joint on the headset
    assert engine.transitions("a") == 1


def test_delayed_emission_lags_by_tau_and_shows_the_same_poses_later(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """The paper's setting emits frame ``n - tau`` at tick ``n``. With no transition
    and no pelvis smoothing (the only pass that reads a frame's neighbours) the poses
    are those the present engine emits, ``tau`` ticks later."""
    frames = {"a": walk_frames(0)}
    outs = []
    for cfg in ({}, {"lookahead": 3, "delayed_emission": True}):
        engine = make_engine(samples=4, pelvis_smoothing=False, **cfg)
        engine.add_player("a", seed=1, selector=Never())
        outs.append(run(engine, frames)["a"])
    present, late = outs
    assert len(late) == len(present) - 3
    assert [p.seq for p in late] == list(range(len(late)))
    a, b = present[: len(late)], late
    for p, q in zip(a, b, strict=True):
        assert (p.seq, p.sample) == (q.seq, q.sample)
    np.testing.assert_allclose(
        np.array([p.positions for p in a]), np.array([p.positions for p in b]), atol=1e-5
    )


def test_a_transition_starts_blending_at_the_frame_after_its_detection(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """Present, tau = 0: the switch asked at tick 31 (frame 30) shows frame 30 on the
    old sample and blends over the next ``T`` frames; tau = 3 shows frame 30 already
    3/T of the way (the look-ahead's head start)."""
    frames = {"a": walk_frames(0)}
    for tau, first in ((0, 31), (3, 30)):
        engine = make_engine(samples=10, lookahead=tau, transition_frames=10)
        engine.add_player("a", seed=1, selector=Forced(at=31, to=4))
        poses = run(engine, frames)["a"]
        blending = [p.seq for p in poses if p.transitioning]
        assert blending[0] == first, tau
        assert poses[first + len(blending)].sample == 4 and not poses[-1].transitioning


def _forecast_run(
    engine: Engine, frames: list[TrackerFrame], ms: float, at: int = 0
) -> list[PoseOut]:
    out = []
    for t, frame in enumerate(frames):
        if t == at:
            engine.set_forecast("a", ms)
        engine.push("a", frame)
        out += engine.tick().poses
    return out


def test_a_forecast_extrapolates_the_shown_poses_and_says_how_far(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """``set_forecast(player, 67)``: once ``HISTORY`` poses are shown, each pose is
    :func:`~posecast.body.forecast.forecast` of the poses the engine would have shown,
    67 ms (4.02 frames) ahead, marked ``ahead_ms``; 0 turns it off."""
    frames = walk_frames(0)[:40]
    plain_engine = make_engine(samples=4)
    plain_engine.add_player("a", seed=1)
    plain = _forecast_run(plain_engine, frames, 0.0)
    engine = make_engine(samples=4)
    engine.add_player("a", seed=1)
    ahead = _forecast_run(engine, frames, 67.0)
    assert [p.ahead_ms for p in ahead] == [0.0] * (HISTORY - 1) + [67.0] * (40 - HISTORY + 1)
    pos = np.array([p.positions for p in plain], np.float64)
    rot = np.array([p.rotations for p in plain], np.float64)
    for t in (HISTORY - 1, 20, 39):
        window = slice(t - HISTORY + 1, t + 1)
        want, _ = forecast(pos[None, window], rot[None, window], np.array([4.02]), 60.0)
        np.testing.assert_allclose(ahead[t].positions, want[0], atol=1e-5)
        assert ahead[t].seq == plain[t].seq == t  # still frame t's, predicted ahead
    moved = np.linalg.norm(ahead[20].positions - plain[20].positions, axis=-1).max()
    assert moved > 1e-3  # the walk moves: the forecast is not the shown pose
    engine.set_forecast("a", 0.0)
    engine.push("a", frames[0])
    assert engine.tick().poses[0].ahead_ms == 0.0


@pytest.mark.parametrize("ms", [-1.0, 100.5, float("nan")])
def test_a_forecast_beyond_its_range_is_refused(make_engine: MakeEngine, ms: float) -> None:
    engine = make_engine(samples=2)
    engine.add_player("a", seed=1)
    with pytest.raises(ValueError, match="forecast_ms"):
        engine.set_forecast("a", ms)
