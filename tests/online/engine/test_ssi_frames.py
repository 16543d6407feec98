"""The batched look-ahead SSI engine (paper Sec. 3.2), frame by frame: look-ahead delay,
batching, joins and leaves, missing frames, calibration. Determinism and transitions:
test_ssi.py."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.online.engine.calibration import Calibration
from posecast.online.engine.selectors import AnomalySelector, SampleSelector
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import EngineEvent, EngineEventKind, PoseOut, TrackerFrame
from posecast.skeleton import NUM_JOINTS, Joint
from tests.online.engine.ssi_helpers import (
    Forced,
    MakeEngine,
    WalkFrames,
    assert_same_poses,
    positions,
    run,
)

# --- look-ahead delay -------------------------------------------------------------------


@pytest.mark.parametrize(("tau", "delayed"), [(0, True), (3, True), (10, True), (10, False)])
def test_output_lags_input_by_exactly_its_delay(
    make_engine: MakeEngine, walk_frames: WalkFrames, tau: int, delayed: bool
) -> None:
    """With ``lookahead = tau`` and ``delayed_emission`` (the paper's) nothing comes out
    for ticks 0 .. tau-1; from tick tau on, each tick emits one pose whose seq is that
    of the frame pushed tau ticks earlier (tau = 0: the frame pushed this tick).
    Without ``delayed_emission`` (the default) every tick emits the frame pushed on it,
    whatever ``tau``."""
    frames = walk_frames(0)[:30]
    seqs = [1000 + 7 * i for i in range(len(frames))]
    engine = make_engine(samples=10, lookahead=tau, delayed_emission=delayed)
    assert engine.cfg.delay == (tau if delayed else 0)
    tau = engine.cfg.delay
    engine.add_player("p", seed=0)
    for t, (frame, seq) in enumerate(zip(frames, seqs, strict=True)):
        engine.push("p", TrackerFrame(seq, frame.pos, frame.quat))
        poses = engine.tick().poses
        if t < tau:
            assert poses == []
        else:
            assert [p.seq for p in poses] == [seqs[t - tau]]
            assert poses[0].player == "p"
            assert poses[0].positions.shape == (NUM_JOINTS, 3)
            assert poses[0].rotations.shape == (NUM_JOINTS, 4)
            assert poses[0].contacts.shape == (2,)
            assert not poses[0].held


def test_the_newest_push_before_a_tick_wins(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    frames = walk_frames(0)
    engine = make_engine(samples=10, lookahead=0, delayed_emission=True)
    engine.add_player("p", seed=0)
    engine.push("p", frames[0])
    engine.push("p", frames[1])
    assert [p.seq for p in engine.tick().poses] == [1]


# --- batching and membership ------------------------------------------------------------


def test_batched_players_equal_single_player_runs(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """Three players with different seeds and walks in one engine give the poses of three
    one-player engines (to 1e-5), transitions and their timing included. p0 runs the
    paper's literal outlier rule (it hops often); p1 and p2 are forced to switch once."""
    players = {"p0": (10, 0), "p1": (11, 1), "p2": (12, 2)}  # id: (seed, walk)
    frames = {pid: walk_frames(walk) for pid, (_, walk) in players.items()}

    def selector(pid: str) -> SampleSelector:
        if pid == "p0":
            return AnomalySelector(baseline="zero")
        return Forced(at=10) if pid == "p1" else Forced(at=20, to=3)

    batched = make_engine(samples=10, lookahead=5, delayed_emission=True)
    for pid, (seed, _) in players.items():
        batched.add_player(pid, seed=seed, selector=selector(pid))
    together = run(batched, frames)
    for pid, (seed, _) in players.items():
        single = make_engine(samples=10, lookahead=5, delayed_emission=True)
        single.add_player(pid, seed=seed, selector=selector(pid))
        alone = run(single, {pid: frames[pid]})
        assert_same_poses(together[pid], alone[pid], atol=1e-5)
        assert batched.transitions(pid) == single.transitions(pid)
    assert sum(batched.transitions(pid) for pid in players) > 0  # interpolation ran batched


def test_players_join_and_leave_between_ticks(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """Add a, b, c; tick; remove b (c moves into its slot); add d; keep ticking. The
    remaining players' poses equal those of a room where b stays, and d's equal a
    room of d alone."""
    walks = {"a": walk_frames(0), "b": walk_frames(1), "c": walk_frames(2), "d": walk_frames(3)}
    seeds = {"a": 1, "b": 2, "c": 3, "d": 4}

    def room(leave: bool) -> tuple[Engine, dict[str, list[PoseOut]]]:
        engine = make_engine(
            samples=10, lookahead=3, delayed_emission=True, capacity=2
        )  # grows on the 3rd join
        out: dict[str, list[PoseOut]] = {p: [] for p in walks}
        for pid in "abc":
            engine.add_player(pid, seed=seeds[pid])
        for t in range(40):
            if t == 10:
                if leave:
                    engine.remove_player("b")
                engine.add_player("d", seed=seeds["d"])
            for pid in engine.players:
                engine.push(pid, walks[pid][t - 10 if pid == "d" else t])
            for pose in engine.tick().poses:
                out[pose.player].append(pose)
        return engine, out

    left, out = room(leave=True)
    stayed, ref = room(leave=False)
    assert left.player_count == 3 and stayed.player_count == 4
    assert sorted(left.players) == ["a", "c", "d"]
    assert [left.players[p].slot for p in ("a", "c", "d")] == [0, 1, 2]
    assert len(out["b"]) == 10 - 3
    for pid in ("a", "c", "d"):
        assert len(out[pid]) == (40 if pid != "d" else 30) - 3
        assert_same_poses(out[pid], ref[pid], atol=1e-5)
    alone = make_engine(samples=10, lookahead=3, delayed_emission=True)
    alone.add_player("d", seed=seeds["d"])
    assert_same_poses(out["d"], run(alone, {"d": walks["d"][:30]})["d"], atol=1e-5)
    with pytest.raises(ValueError, match="already"):
        left.add_player("a", seed=9)


def test_an_empty_engine_ticks(make_engine: MakeEngine) -> None:
    engine = make_engine(samples=10)
    result = engine.tick()
    assert (result.poses, result.events, result.transitions) == ([], [], 0)
    engine.add_player("a", seed=0)
    engine.remove_player("a")
    assert engine.player_count == 0
    assert engine.tick().poses == []


# --- missing frames -----------------------------------------------------------------------


def test_missing_frames_are_held_then_stale_then_active(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """tau = 2, stale after 5 frames. Frame 6 is missing: the pose for it (out at tick 8)
    is marked held and repeats frame 5's seq. From tick 10 no frames come: one "stale"
    event on the 5th empty tick (14), none after; the frame at tick 17 brings "active"."""
    frames = walk_frames(0)
    engine = make_engine(samples=10, lookahead=2, delayed_emission=True, stale_after_frames=5)
    engine.add_player("p", seed=0)
    engine.add_player("q", seed=1)  # always on time: never held, never stale
    poses: dict[int, PoseOut] = {}
    events: dict[int, list[EngineEvent]] = {}
    for t in range(20):
        if t != 6 and not 10 <= t <= 16:
            engine.push("p", frames[t])
        engine.push("q", frames[t])
        result = engine.tick()
        events[t] = result.events
        for pose in result.poses:
            if pose.player == "p":
                poses[t] = pose
            else:
                assert not pose.held
    assert sorted(poses) == list(range(2, 20))  # a pose every tick, held or not
    held = {t for t, p in poses.items() if p.held}
    assert held == {8, *range(12, 19)}
    assert poses[8].seq == 5 and poses[7].seq == 5 and poses[9].seq == 7
    assert [poses[t].seq for t in range(12, 19)] == [9] * 7
    assert poses[19].seq == 17 and not poses[19].held
    assert {t: e for t, e in events.items() if e} == {
        14: [EngineEvent(EngineEventKind.STALE, "p")],
        17: [EngineEvent(EngineEventKind.ACTIVE, "p")],
    }
    assert events[14][0].kind is EngineEventKind.STALE  # the member, not an equal string


def test_a_frame_after_missing_ones_reads_its_velocity_over_the_gap(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """``p`` misses frames 10-24 of the walk: the frame it resumes on moved over all 16
    frame times since frame 9, so its velocities are the mean velocity over the gap
    (before the fix: 16 times that, 17 m/s for a walk's hands), its positions the frame's."""
    from posecast.tracking.layouts import Layout, spec

    frames = walk_frames(0)
    engine = make_engine(samples=10, lookahead=3, delayed_emission=True)
    engine.add_player("p", seed=1)
    for t in range(26):
        if not 10 <= t < 25:
            engine.push("p", frames[t])
        engine.tick()
        if t == 9:
            _, before, _ = engine.newest_inputs("p")
    x, pos, quat = engine.newest_inputs("p")
    prev = pos - (pos - before) / 16
    want = spec(Layout.HMD3_WAIST).features(pos[None], prev[None], quat[None], 60.0, None)[0]
    np.testing.assert_allclose(x, want, atol=1e-5)
    assert np.abs(x).max() < 3.0  # a walk


def test_the_waist_filter_starts_on_the_first_real_frame(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """A player joined five ticks before its first frame (rest frames stand in, facing
    +Z): its filtered waist is the same as a player's whose frames came at once, not
    dragged from the rest frame's heading (100 degrees off on a walk facing away)."""
    from posecast.geometry.rotations import quat_mul, yaw2quat
    from posecast.tracking.features import TrackerSlot

    turn = yaw2quat(np.pi * 0.9)
    frames = [TrackerFrame(f.seq, f.pos, quat_mul(turn, f.quat)) for f in walk_frames(0)[:6]]
    waists = []
    for rest in (0, 5):
        engine = make_engine(samples=4, lookahead=2, delayed_emission=True, waist_filter_hz=4.0)
        engine.add_player("p", seed=1)
        for _ in range(rest):
            engine.tick()
        got = []
        for f in frames:
            engine.push("p", f)
            engine.tick()
            got.append(engine.newest_inputs("p")[2][TrackerSlot.WAIST])
        waists.append(np.array(got))
    np.testing.assert_allclose(waists[1], waists[0], atol=1e-12)


def test_the_last_rest_frame_is_not_smoothed_toward_the_first_real_one(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """A player joined before its first frame stands at the origin until that frame,
    3 m away, is shown: the pelvis smoothing does not pull the last rest pose a
    quarter of the way there (0.75 m before the fix)."""
    frames = _three_metres_away(walk_frames(0))
    engine = make_engine(samples=4, lookahead=2, delayed_emission=True)
    engine.add_player("p", seed=1)
    shown = []
    for t in range(8):
        if t >= 4:
            engine.push("p", frames[t - 4])
        shown += [(pose.seq, pose.positions[0, 0]) for pose in engine.tick().poses]
    rest = [x for seq, x in shown if seq < 0]
    real = [x for seq, x in shown if seq >= 0]
    assert len(rest) == 4 and len(real) == 2
    assert max(abs(x) for x in rest) < 1e-6
    assert min(real) > 2.9


def test_a_player_without_any_frame_stands_at_the_origin(make_engine: MakeEngine) -> None:
    engine = make_engine(samples=10, lookahead=0, delayed_emission=True, stale_after_frames=3)
    engine.add_player("p", seed=0)
    results = [engine.tick() for _ in range(3)]
    for r in results:
        (pose,) = r.poses
        assert pose.held and pose.seq == -1
        assert np.all(np.isfinite(pose.positions))
        assert abs(pose.positions[0, 0]) < 1e-6 and abs(pose.positions[0, 2]) < 1e-6
    assert [r.events for r in results] == [[], [], [EngineEvent(EngineEventKind.STALE, "p")]]


# --- calibration ------------------------------------------------------------------------


def test_output_is_at_the_users_own_scale(make_engine: MakeEngine, walk_frames: WalkFrames) -> None:
    """A half-size user with ``scale = 2`` feeds the network the canonical walk; the poses
    come back at half size, where the user stands."""
    frames = walk_frames(0)[:30]
    small = [TrackerFrame(f.seq, f.pos * 0.5, f.quat) for f in frames]
    ref_engine = make_engine(samples=10, lookahead=2, delayed_emission=True)
    ref_engine.add_player("p", seed=0)
    ref = run(ref_engine, {"p": frames})["p"]
    engine = make_engine(samples=10, lookahead=2, delayed_emission=True)
    engine.add_player("p", seed=0, calibration=Calibration(scale=2.0))
    got = run(engine, {"p": small})["p"]
    np.testing.assert_allclose(positions(got), 0.5 * positions(ref), atol=1e-6)
    engine.set_calibration("p", Calibration())
    assert engine.players["p"].calibration == Calibration()


def test_a_new_calibration_reaches_the_frames_already_in_the_look_ahead(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """A player walking 3 m from the origin is calibrated anew mid-stream (another
    scale, then a waist offset too): the frames already waiting in the look-ahead are
    shown in the new calibration as every later one, so the head stays on the headset
    on every frame (before the fix the four waiting frames were divided by the new
    scale with the old one in them: 9 cm off), and the next frame's velocities are
    measured from the same calibration (a walk's speed, not a jump)."""
    frames = _three_metres_away(walk_frames(0))
    engine = make_engine(samples=4, lookahead=4, delayed_emission=True)
    engine.add_player("p", seed=1)
    shown = []
    for t in range(40):
        if t == 15:
            engine.set_calibration("p", Calibration(scale=0.97))
        if t == 25:
            engine.set_calibration("p", Calibration(scale=0.97, waist_offset_m=(0.0, -0.01, 0.01)))
        engine.push("p", frames[t])
        shown += engine.tick().poses
        assert np.abs(engine.newest_inputs("p")[0]).max() < 3.0, t
    assert [p.seq for p in shown] == list(range(36))
    head = np.array([p.positions[Joint.HEAD] for p in shown])
    headset = np.array([frames[p.seq].pos[0] for p in shown])
    assert np.linalg.norm(head - headset, axis=-1).max() < 1e-3
    assert [p.scale for p in shown] == [1.0] * 11 + [pytest.approx(0.97)] * 25


def test_a_new_scale_re_expresses_the_shown_poses_positional_state(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """The shown pose's state in tracker space (contact locks, the clearance's toes,
    the reach move, the planted toes' positions and trails) is scaled with the
    calibration, so the next frame measures its steps within one calibration."""
    engine = make_engine(samples=4)
    engine.add_player("p", seed=1)
    for f in walk_frames(0)[:8]:
        engine.push("p", f)
        engine.tick()
    slot = engine.players["p"].slot
    names = ("disp_lock_pos", "disp_toe_xz", "disp_reach", "disp_plant_xz", "disp_plant_offset")
    before = {n: engine.slots[n][slot].copy() for n in names}
    assert np.abs(before["disp_plant_xz"]).max() > 0.01  # the toes stand somewhere
    engine.set_calibration("p", Calibration(scale=1.25))
    for n in names:
        np.testing.assert_allclose(engine.slots[n][slot], 1.25 * before[n], err_msg=n)


def test_a_new_calibration_reorients_the_frames_already_held(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """Device rotation offsets that change mid-stream turn the held frames' orientations
    as the new calibration would have turned them on arrival, and a scale the
    positions."""
    from posecast.geometry.rotations import quat_mul, quat_normalize, yaw2quat

    frames = walk_frames(0)
    engine = make_engine(samples=4, lookahead=2, delayed_emission=True)
    engine.add_player("p", seed=1)
    for f in frames[:5]:
        engine.push("p", f)
        engine.tick()
    offsets = tuple(tuple(map(float, yaw2quat(0.3 * (i + 1)))) for i in range(4))
    cal = Calibration(scale=1.1, rot_offsets=offsets)  # type: ignore[arg-type]
    engine.set_calibration("p", cal)
    _, pos, quat = engine.newest_inputs("p")
    np.testing.assert_allclose(pos, cal.apply(frames[4].pos, quat), atol=1e-12)
    want = quat_normalize(quat_mul(frames[4].quat, np.asarray(offsets)))
    np.testing.assert_allclose(np.abs((quat * want).sum(-1)), 1.0, atol=1e-12)


def test_a_default_selector_is_the_engines_configured_one(make_engine: MakeEngine) -> None:
    """What a backend's ``selector`` of kind ``anomaly`` asks for: the anomaly selector
    the engine gives every player (its baseline and its ``home``, sample 0), with the
    message's factor; not the class's bare defaults, which turned ``home`` off."""
    from posecast.online.engine.selectors import DefaultSelector

    engine = make_engine(samples=4, outlier_factor=2.5, home_factor=1.0, outlier_baseline="min")
    engine.add_player("p", seed=0)
    first = engine.players["p"].selector
    assert first == AnomalySelector(2.5, "min", 1.0)
    engine.set_selector("p", DefaultSelector(3.0))
    assert engine.players["p"].selector == AnomalySelector(3.0, "min", 1.0)
    engine.set_selector("p", DefaultSelector(0.5))  # home never above the factor
    assert engine.players["p"].selector == AnomalySelector(0.5, "min", 0.5)
    engine.set_selector("p", DefaultSelector())
    assert engine.players["p"].selector == first


def _three_metres_away(frames: list[TrackerFrame]) -> list[TrackerFrame]:
    """A walk 3 m along +X from the origin, where a misplaced pose shows."""
    return [TrackerFrame(f.seq, f.pos + np.array([3.0, 0.0, 0.0]), f.quat) for f in frames]
