"""The jitter buffer: the shared table ``proto/vectors/sdk/interp.json``, then the
parts the table does not reach (slerp itself, config checks, the per-player router)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import posecast_client as pc
from posecast_client.interp import InterpConfig, Interpolator, PoseBuffer, quat_slerp

TABLE = Path(__file__).resolve().parents[3] / "proto" / "vectors" / "sdk" / "interp.json"
VECTORS: dict[str, Any] = json.loads(TABLE.read_text("utf-8")) if TABLE.exists() else {}

needs_table = pytest.mark.skipif(not VECTORS, reason="proto/vectors/sdk not found (repo only)")


def to_pose(p: dict[str, Any], player: str = "p") -> pc.Pose:
    rot = None if p["rotations"] is None else np.array(p["rotations"])
    return pc.Pose(player, p["seq"], p["t"], np.array(p["positions"]), rot)


def same_rotations(got: np.ndarray, want: np.ndarray, tol: float) -> bool:
    """Joint by joint, ``q`` and ``-q`` being the same rotation."""
    err = np.minimum(np.abs(got - want).max(-1), np.abs(got + want).max(-1))
    return bool(err.max() <= tol)


@needs_table
@pytest.mark.parametrize("case", VECTORS.get("cases", []), ids=lambda c: c["name"])
def test_interp_vector(case: dict[str, Any]) -> None:
    tol = VECTORS["tolerance"]
    buf = PoseBuffer(InterpConfig(**case["config"]))
    for k, step in enumerate(case["steps"]):
        if "push" in step:
            got = buf.push(to_pose(step["push"]), keyframe=step["push"]["keyframe"])
            assert got == step["accepted"], f"step {k}"
            continue
        shown, want = buf.pose_at(step["query"]), step["expect"]
        if want is None:
            assert shown is None, f"step {k}"
            continue
        assert shown is not None, f"step {k}"
        assert (shown.mode, shown.seq, shown.player) == (want["mode"], want["seq"], "p"), k
        assert shown.t == pytest.approx(want["t"], abs=1e-12)
        np.testing.assert_allclose(shown.positions, want["positions"], atol=tol["position_m"])
        if want["rotations"] is None:
            assert shown.rotations is None, f"step {k}"
        else:
            assert shown.rotations is not None, f"step {k}"
            assert same_rotations(shown.rotations, np.array(want["rotations"]), tol["rotation"])


@needs_table
def test_the_table_config_is_the_sdk_config() -> None:
    """Every case names every knob, with the SDK's own names and defaults; the rules
    are pinned at a fixed delay (``delay.json`` pins the adaptive one)."""
    names = {f.name for f in fields(InterpConfig)}
    defaults = {f.name: f.default for f in fields(InterpConfig)}
    assert all(set(c["config"]) == names for c in VECTORS["cases"])
    assert VECTORS["cases"][0]["config"] == {**defaults, "adaptive": False}


def axis_angle(axis: list[float], angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return np.array([*(a * math.sin(angle / 2)), math.cos(angle / 2)])


def angle_between(q0: np.ndarray, q1: np.ndarray) -> float:
    return 2.0 * math.acos(min(1.0, abs(float(np.dot(q0, q1)))))


def test_slerp_turns_at_a_constant_rate_on_the_short_arc() -> None:
    q0, q1 = axis_angle([1, 2, 3], 0.3), axis_angle([1, 2, 3], 0.3 + 2.6)  # 149 degrees
    for u in (0.0, 0.1, 0.5, 0.9, 1.0, 1.2):  # 1.2: extrapolated, still under 180
        q = quat_slerp(q0, q1, u)
        assert np.linalg.norm(q) == pytest.approx(1.0)
        assert angle_between(q0, q) == pytest.approx(2.6 * u, abs=1e-9)
    assert np.allclose(quat_slerp(q0, -q1, 0.25), quat_slerp(q0, q1, 0.25))  # hemisphere
    # Past 180 degrees the short way goes round the other side: 200 degrees is -160.
    rest, far = axis_angle([0, 1, 0], 0.0), axis_angle([0, 1, 0], math.radians(200))
    half = quat_slerp(rest, far, 0.5)
    assert angle_between(rest, half) == pytest.approx(math.radians(80), abs=1e-9)
    same = axis_angle([0, 0, 1], 1e-9)  # nearly equal: no division blow-up
    assert np.allclose(quat_slerp(rest, same, 0.5), rest, atol=1e-9)


@pytest.mark.parametrize(
    "bad",
    [
        {"delay_s": -0.1},
        {"delay_s": math.nan},
        {"max_extrapolate_s": math.inf},
        {"teleport_m": 0.0},
        {"gap_s": -1.0},
        {"capacity": 1},
        {"correction_s": -0.01},
        {"min_delay_s": 0.3},  # above max_delay_s
        {"max_delay_s": math.inf},
        {"delay_quantile": 0.0},
        {"delay_quantile": 1.5},
        {"delay_window": 0},
        {"delay_slew": -0.05},
        {"delay_margin_s": math.nan},
    ],
)
def test_bad_config_is_refused(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        InterpConfig(**bad)  # type: ignore[arg-type]


def walk_pose(player: str, seq: int, t: float) -> pc.Pose:
    """Every joint at ``(t, 1, 0)`` and turned ``t`` radians about +Y."""
    pos = np.tile([t, 1.0, 0.0], (19, 1))
    rot = np.tile(axis_angle([0, 1, 0], t), (19, 1))
    return pc.Pose(player, seq, t, pos, rot)


def test_interpolator_routes_forgets_and_clears() -> None:
    interp = Interpolator(max_players=2)
    for k in range(3):
        for player in ("ada", "bo"):
            interp.feed(walk_pose(player, k, 10.0 + k / 60))
    shown = interp.poses_at(10.0 + 1.5 / 60 + interp.config.delay_s)
    assert set(shown) == {"ada", "bo"} and shown["ada"].mode == "interpolate"
    assert shown["ada"].positions[0, 0] == pytest.approx(10.0 + 1.5 / 60)
    interp.push(walk_pose("cy", 0, 10.0))  # a third player: "ada" was heard from first
    assert interp.players == ("bo", "cy")
    interp.feed(pc.Presence("leave", "room", "bo", "Bo"))
    assert interp.players == ("cy",) and interp.pose_at("bo", 11.0) is None
    interp.feed(pc.Presence("stale", "room", "cy", "Cy"))  # stale keeps the buffer
    assert interp.players == ("cy",)
    welcome = pc.Welcome(1, "me", "s", "player", "room", 0.0, 60.0, 10, (), pc.DEFAULT_LIMITS)
    interp.feed(welcome)  # a (re)join: maybe another server clock
    assert interp.players == ()


def test_memory_stays_bounded_over_a_long_stream() -> None:
    buf = PoseBuffer(InterpConfig(capacity=8))
    for k in range(10_000):
        buf.push(walk_pose("ada", k, k / 60))
        buf.pose_at(k / 60)
    assert len(buf) == 8 and buf.newest_t == pytest.approx(9_999 / 60)


def test_arrival_jitter_under_the_delay_does_not_show() -> None:
    """Seeded arrival jitter of 0-40 ms under a fixed 100 ms delay: the stream sampled
    at 90 Hz is the clean one, exactly, because the buffer reads server times only."""
    rng = np.random.default_rng(3)
    sent = [walk_pose("ada", k, 5.0 + k / 60) for k in range(120)]
    arrive = [p.t + rng.uniform(0.0, 0.040) for p in sent]
    fixed = InterpConfig(adaptive=False)
    jittery, clean = PoseBuffer(fixed), PoseBuffer(fixed)
    order = sorted(range(len(sent)), key=lambda k: arrive[k])
    nxt = 0
    for frame in range(150):
        now = 5.2 + frame / 90
        while nxt < len(order) and arrive[order[nxt]] <= now:
            jittery.push(sent[order[nxt]])
            nxt += 1
        for p in sent:
            if p.t <= now:
                clean.push(p)  # duplicates are refused, so this is "everything sent so far"
        a, b = jittery.pose_at(now), clean.pose_at(now)
        assert a is not None and b is not None
        np.testing.assert_allclose(a.positions, b.positions, atol=1e-12)


def test_feed_takes_a_v2_keyframe_as_a_resync_point() -> None:
    """A keyframe whose seq is not newer (a new sequence: a rejoin) starts a new segment
    (no blend across it) when it arrives through ``feed``, exactly as
    ``push(..., keyframe=True)``."""
    shown = {}
    for how in ("feed", "push", "plain"):
        interp = Interpolator()
        first, after_gap = walk_pose("p", 500, 10.0), walk_pose("p", 0, 10.0 + 1 / 60)
        keyed = dataclasses.replace(after_gap, keyframe=True)
        if how == "feed":
            interp.feed(first)
            interp.feed(keyed)
        elif how == "push":
            interp.push(first)
            interp.push(after_gap, keyframe=True)
        else:
            interp.push(first)
            interp.push(after_gap)
        got = interp.pose_at("p", 10.0 + 0.5 / 60 + interp.config.delay_s)
        assert got is not None
        shown[how] = got
    assert shown["plain"].mode == "interpolate"
    assert shown["feed"].mode == shown["push"].mode != "interpolate"
    np.testing.assert_array_equal(shown["feed"].positions, shown["push"].positions)


def test_a_keyframe_after_a_forward_seq_step_blends() -> None:
    """At a 30 Hz pose rate (or from a 90-120 Hz sender) seq steps by 2 or more on every
    pose, and the server's keyframe (one a second) comes on such a step: it blends like
    any other pose instead of snapping once a second."""
    interp = Interpolator()
    for k in range(4):  # 30 Hz poses of a 60 Hz sender: seq 0, 2, 4, 6; 4 is a keyframe
        pose = walk_pose("p", 2 * k, 10.0 + k / 30)
        interp.feed(dataclasses.replace(pose, keyframe=k in (0, 2)))
    got = interp.pose_at("p", 10.0 + 1.5 / 30 + interp.config.delay_s)
    assert got is not None and got.mode == "interpolate"
    assert got.positions[0, 0] == pytest.approx(10.0 + 1.5 / 30)
