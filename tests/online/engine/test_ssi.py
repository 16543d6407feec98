"""The batched look-ahead SSI engine (paper Sec. 3.2): determinism, outlier-triggered
transitions, smoothness, look-ahead delay, batching, joins and leaves, missing frames."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pytest

from posecast.online.engine.calibration import Calibration
from posecast.online.engine.ports import Pool, StepDecoder
from posecast.online.engine.selectors import AnomalySelector, SampleSelector
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import EngineEvent, EngineEventKind, PoseOut, TrackerFrame
from posecast.skeleton import NUM_JOINTS, Joint
from tests.online.engine.conftest import BackendLoader

MakeEngine = Callable[..., Engine]
WalkFrames = Callable[..., list[TrackerFrame]]


class Never:
    """A selector that always stays: holds a player on its first sample (no transitions)."""

    def choose(self, current: int, scores: np.ndarray, positions: np.ndarray) -> int | None:
        return None


class Forced:
    """Stay, except on call ``at`` (1-based): then move to ``to``, or, with ``to=None``, to
    the sample of least anomaly error among the others (what the anomaly selector picks)."""

    def __init__(self, at: int, to: int | None = None) -> None:
        self.at, self.to, self.calls = at, to, 0
        self.chosen: int | None = None

    def choose(self, current: int, scores: np.ndarray, positions: np.ndarray) -> int | None:
        self.calls += 1
        if self.calls != self.at:
            return None
        others = scores.astype(np.float64).copy()
        others[current] = np.inf
        self.chosen = int(np.argmin(others)) if self.to is None else self.to
        return self.chosen


class RecordingPool:
    """The backend's pool, keeping the scores ``(P*N,)`` of the latest step."""

    def __init__(self, pool: Pool) -> None:
        self.pool, self.threshold_m = pool, pool.threshold_m
        self.last = np.zeros(0)

    def step(self, *args: Any) -> np.ndarray:
        scores: np.ndarray = self.pool.step(*args)
        self.last = scores.copy()
        return scores

    def emit(self, *args: Any) -> tuple[np.ndarray, np.ndarray]:
        return self.pool.emit(*args)

    def upper_body(self, *args: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.pool.upper_body(*args)

    def hinge(self, *args: Any) -> None:
        self.pool.hinge(*args)


class NoContacts:
    """The backend's decoder with its foot contacts forced to 0, so no contact IK runs
    and positions show the decoder's poses (and the SSI interpolation) alone."""

    def __init__(self, decoder: StepDecoder) -> None:
        self.decoder, self.meta, self.name = decoder, decoder.meta, decoder.name
        self.cache_width = decoder.cache_width

    def cache_latents(self, eps: np.ndarray) -> np.ndarray:
        return self.decoder.cache_latents(eps)

    def step(
        self,
        features: np.ndarray,
        group: int,
        cache: np.ndarray,
        h: np.ndarray,
        out: Mapping[str, np.ndarray],
    ) -> None:
        self.decoder.step(features, group, cache, h, out)
        out["contacts"][...] = 0.0


def run(engine: Engine, frames: dict[str, list[TrackerFrame]]) -> dict[str, list[PoseOut]]:
    """Push every player's next frame and tick, until the longest walk is through."""
    out: dict[str, list[PoseOut]] = {pid: [] for pid in frames}
    for t in range(max(len(f) for f in frames.values())):
        for pid, fs in frames.items():
            if t < len(fs):
                engine.push(pid, fs[t])
        for pose in engine.tick().poses:
            out.setdefault(pose.player, []).append(pose)
    return out


def positions(poses: list[PoseOut]) -> np.ndarray:
    return np.array([p.positions for p in poses])


def max_joint_jumps(pos: np.ndarray) -> np.ndarray:
    """Largest joint displacement between consecutive frames ``(F-1,)``, metres."""
    out: np.ndarray = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(axis=-1)
    return out


def assert_same_poses(a: list[PoseOut], b: list[PoseOut], atol: float = 0.0) -> None:
    assert len(a) == len(b)
    assert [(p.seq, p.sample, p.transitioning, p.held) for p in a] == [
        (p.seq, p.sample, p.transitioning, p.held) for p in b
    ]
    for name in ("positions", "rotations", "contacts"):
        np.testing.assert_allclose(
            np.array([getattr(p, name) for p in a]),
            np.array([getattr(p, name) for p in b]),
            atol=atol,
            rtol=0.0,
            err_msg=name,
        )


# --- determinism ----------------------------------------------------------------------


def test_same_seeds_give_identical_poses(make_engine: MakeEngine, walk_frames: WalkFrames) -> None:
    """Two engines, same seeds, same frames: the same poses, bit for bit. Player ``b`` is
    made to switch samples at tick 30, so interpolated frames are compared too."""
    frames = {"a": walk_frames(0), "b": walk_frames(1)}
    outs = []
    for _ in range(2):
        engine = make_engine(samples=10, lookahead=5, delayed_emission=True)
        engine.add_player("a", seed=1)
        engine.add_player("b", seed=2, selector=Forced(at=31, to=4))
        outs.append(run(engine, frames))
        assert engine.transitions("b") == 1
    for pid in frames:
        assert len(outs[0][pid]) == 90 - 5
        assert_same_poses(outs[0][pid], outs[1][pid])
    assert any(p.transitioning for p in outs[0]["b"])


def test_the_seed_draws_the_latent_samples(make_engine: MakeEngine) -> None:
    """Different seeds draw different latent samples; sample 0 is always the prior's
    mean (``eps = 0``), so different seeds agree until a transition leaves it."""
    engine = make_engine(samples=10)
    for pid, seed in (("a", 1), ("b", 1), ("c", 2)):
        engine.add_player(pid, seed=seed)
    eps = engine.slots.view("eps")  # (P, N, latent)
    np.testing.assert_array_equal(eps[0], eps[1])
    np.testing.assert_array_equal(eps[:, 0], 0.0)
    assert np.all(np.any(eps[0, 1:] != eps[2, 1:], axis=-1))
    assert all(engine.current_sample(p) == 0 for p in "abc")


def test_latent_scale_truncates_the_pool(make_engine: MakeEngine) -> None:
    """``latent_scale`` draws the same samples, scaled: a truncated pool nearer the mean."""
    full, half = make_engine(samples=10), make_engine(samples=10, latent_scale=0.5)
    full.add_player("a", seed=3)
    half.add_player("a", seed=3)
    np.testing.assert_allclose(
        half.slots.view("eps")[0], 0.5 * full.slots.view("eps")[0], rtol=1e-6
    )


def test_a_different_seed_gives_a_different_sample(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """Shown from the start on sample 5, the same walk differs between seeds 1 and 2."""
    shown = []
    for seed in (1, 2):
        engine = make_engine(samples=10, lookahead=10, delayed_emission=True)
        engine.add_player("p", seed=seed, selector=Forced(at=1, to=5))
        poses = run(engine, {"p": walk_frames(0)[:30]})["p"]
        assert all(p.sample == 5 and not p.transitioning for p in poses)
        shown.append(positions(poses))
    assert np.abs(shown[0] - shown[1]).max() > 1e-3


# --- outlier -> transition to the best sample -------------------------------------------


WARMUP = 20  # frames before the injection


Corruption = Callable[[Engine, int, int], None]  # (engine, slot, sample)


def corrupt_hidden(value: float | np.ndarray) -> Corruption:
    def apply(engine: Engine, slot: int, sample: int) -> None:
        engine.hidden_state(engine._order[slot])[sample] = value

    return apply


def corrupt_latent(value: np.ndarray) -> Corruption:
    def apply(engine: Engine, slot: int, sample: int) -> None:
        engine.set_latents(engine._order[slot], value, sample)

    return apply


def inject(
    make_engine: MakeEngine,
    frames: list[TrackerFrame],
    corrupt: Corruption,
) -> tuple[Engine, list[tuple[int, np.ndarray, int, int]], list[PoseOut]]:
    """Walk ``WARMUP`` frames on sample 0, then corrupt its GRU state or latent and let
    the anomaly selector run. Returns the engine, per tick from the injection on
    ``(tick, R (N,), transitions started, current sample after the tick)``, and poses.

    Stops 10 ticks after the first transition (when its last frame is out), or 2 ticks
    after the injection if none has started by then.
    """
    engine = make_engine(samples=20, lookahead=10, delayed_emission=True, transition_frames=10)
    engine.pool = scorer = RecordingPool(engine.pool)
    engine.add_player("p", seed=0, selector=Never())
    log: list[tuple[int, np.ndarray, int, int]] = []
    poses: list[PoseOut] = []
    started: int | None = None
    for t, frame in enumerate(frames):
        if t == WARMUP:
            engine.set_selector("p", AnomalySelector(factor=2.0))
            corrupt(engine, engine.players["p"].slot, engine.current_sample("p"))
        engine.push("p", frame)
        result = engine.tick()
        poses += result.poses
        log.append((t, scorer.last.copy(), result.transitions, engine.current_sample("p")))
        if started is None and t >= WARMUP and result.transitions:
            started = t
        if t == (WARMUP + 2 if started is None else started + 10):
            break
    return engine, log, poses


def is_outlier(scores: np.ndarray, current: int) -> bool:
    """The engine's default trimmed estimator (paper eq. 2): ``R_c > 2 (median R - min R)``
    (computed as the selector does, in the scores' own dtype)."""
    low = float(np.min(scores))
    return bool(scores[current] > 2.0 * (float(np.median(scores)) - low))


def test_an_implausible_sample_triggers_a_transition_to_the_best(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """After 20 frames on sample 0, its GRU hidden state (or latent) is overwritten with
    extreme values, so its pose turns to garbage. Within 3 frames its error ``R`` is an
    outlier under the 2r rule; on exactly that tick a transition starts, to the other
    sample of least ``R``. With ``tau = T = 10`` the 9 frames before the detected one
    are interpolated (``transitioning``) and the detected frame itself already shows
    the new sample.

    Which corruption turns a sample to garbage depends on the trained weights (a
    decoder may saturate into a tame pose for one of them), so a few are tried and
    the first whose ``R`` really is an outlier is used; every check below is exact.
    """
    frames = walk_frames(0)
    rng = np.random.default_rng(0)
    candidates = [
        corrupt_hidden(-5.0),
        corrupt_hidden(3.0 * np.sign(rng.standard_normal(128))),
        corrupt_hidden(5.0),
        corrupt_latent(40.0 * np.ones(30)),
    ]
    for corruption in candidates:
        engine, log, poses = inject(make_engine, frames, corruption)
        started = [t for t, _, n, _ in log if t >= WARMUP and n]
        if started:
            break
    else:
        pytest.fail("no huge latent made the current sample an outlier within 3 frames")

    t_star = started[0]
    assert t_star <= WARMUP + 2
    by_tick = {t: (r, n, cur) for t, r, n, cur in log}
    # Before the transition no outlier was missed.
    for t in range(WARMUP, t_star):
        assert not is_outlier(by_tick[t][0], 0)
    r_star, n_star, cur_star = by_tick[t_star]
    assert n_star == 1
    assert is_outlier(r_star, 0)
    assert r_star[0] > by_tick[WARMUP - 1][0][0]  # the injection made sample 0 worse
    others = r_star.copy()
    others[0] = np.inf
    best = int(np.argmin(others))
    assert cur_star == best == engine.current_sample("p")
    assert engine.transitions("p") == 1

    # Frames out: seq 0 .. t*; interpolated exactly t*-9 .. t*-1, then the best sample.
    by_seq = {p.seq: p for p in poses}
    assert sorted(by_seq) == list(range(t_star + 1))
    for seq, pose in by_seq.items():
        if seq < t_star - 9:
            assert (pose.sample, pose.transitioning) == (0, False), seq
        elif seq < t_star:
            assert (pose.sample, pose.transitioning) == (best, True), seq
        else:
            assert (pose.sample, pose.transitioning) == (best, False), seq


def test_no_new_transition_while_one_is_in_flight(
    make_engine: MakeEngine, walk_frames: WalkFrames
) -> None:
    """The selector is not asked while a transition is under way; it is asked again on
    the tick after the transition's last frame is out."""
    selector = Forced(at=5, to=7)
    engine = make_engine(samples=10, lookahead=3, delayed_emission=True, transition_frames=10)
    engine.add_player("p", seed=3, selector=selector)
    asked = []
    for t, frame in enumerate(walk_frames(0)[:30]):
        before = selector.calls
        engine.push("p", frame)
        engine.tick()
        if selector.calls > before:
            asked.append(t)
    # Chosen at tick 4; first interpolated frame 4-3+1 = 2, last full frame 11, out at
    # tick 14 (tau = 3 behind); asked again from tick 15.
    assert asked == [0, 1, 2, 3, 4, *range(15, 30)]
    assert engine.transitions("p") == 1
    assert engine.current_sample("p") == 7


class SinkingPool(RecordingPool):
    """The backend's pool, with the post-IK poses of one player's samples ``sink`` pushed
    1 m under the floor from its step ``at`` (1-based) on: the selector sees them sunk,
    their anomaly errors (computed before) unchanged."""

    def __init__(self, pool: Pool, samples: int, sink: list[int], at: int) -> None:
        super().__init__(pool)
        self.samples, self.sink, self.at, self.steps = samples, sink, at, 0

    def step(self, *args: Any) -> np.ndarray:
        scores = super().step(*args)
        self.steps += 1
        if self.steps >= self.at:
            world = args[-1].reshape(-1, self.samples, NUM_JOINTS, 3)
            world[:, self.sink, :, 1] -= 1.0
        return scores


@pytest.mark.parametrize("floor_select", [True, False])
def test_ssi_leaves_a_sample_sunk_below_the_floor_for_the_best_standing_one(
    make_engine: MakeEngine, walk_frames: WalkFrames, floor_select: bool
) -> None:
    """After a walk on sample 0, sample 0 and every other even sample sink 1 m under the
    floor, deeper than the floor pass lifts. On that very tick the engine leaves sample
    0 for the odd sample of least anomaly error (home, sample 0, is out of the pool),
    though by its error alone sample 0 is no outlier; with ``floor_select=False`` it
    decides on the errors alone, as the paper's selector would."""
    N, sink = 10, [0, 2, 4, 6, 8]
    engine = make_engine(
        samples=N,
        lookahead=10,
        delayed_emission=True,
        transition_frames=10,
        floor_select=floor_select,
    )
    engine.pool = pool = SinkingPool(engine.pool, N, sink, at=WARMUP + 1)
    engine.add_player("p", seed=0, selector=Never())
    selector = AnomalySelector(factor=2.0, home=1.0)
    for t, frame in enumerate(walk_frames(0)[: WARMUP + 1]):
        if t == WARMUP:
            engine.set_selector("p", selector)
        engine.push("p", frame)
        started = engine.tick().transitions
    raw = pool.last.astype(np.float64)
    by_error = selector.choose(0, raw, np.zeros((N, NUM_JOINTS, 3)))
    standing = [i for i in range(N) if i not in sink]
    best_standing = standing[int(np.argmin(raw[standing]))]
    assert by_error != best_standing  # the errors alone would not choose it
    if floor_select:
        assert (started, engine.current_sample("p")) == (1, best_standing)
    else:
        assert engine.current_sample("p") == (0 if by_error is None else by_error)
        assert started == (0 if by_error is None else 1)


@pytest.mark.parametrize(("tau", "at"), [(10, 25), (3, 60)])
def test_transition_jumps_stay_bounded(
    backend: BackendLoader,
    walk_frames: WalkFrames,
    tau: int,
    at: int,
) -> None:
    """Bound: over a transition (the jumps into each interpolated frame and into the
    first frame of the new sample), the largest per-frame joint jump is at most

        max(J_src, J_dst) + gap / T + 3 cm

    ``J_src`` / ``J_dst``: the largest per-frame joint jump of the same walk shown on
    the old / new sample alone, with no transition (after 5 warm-up frames). ``gap``:
    the largest joint distance between those two runs over the transition; the
    interpolation spreads it over ``T = 10`` frames (an instant switch would jump by
    all of it). 3 cm covers the decoder being nonlinear in the interpolated latent and
    hidden state.

    Contacts are forced off so that the display IK stays out of it: releasing a lock
    the network's ankle has drifted far from snaps the knee straight-to-bent whether a
    transition runs or not, and how far it drifts depends on the trained contacts.
    Contact IK has its own tests in ``test_ik.py``.

    Measured with the early-training weights, N = 20, switching to the least-``R``
    other sample, over 4 engine seeds x 3 walks x (tau, tick) in {10, 3} x {24, 59}:
    jumps 2.6-8.8 cm, ``J_src`` 4.1-5.7 cm, ``gap`` 17-44 cm, at worst 1.4 cm above
    ``max(J_src, J_dst) + gap / T``. The two cases here (engine seed 3, walk seed 1):
    tau = 10 switching at tick 24, 6.2 cm against a bound of 11.8 cm; tau = 3 at tick
    59, 8.8 cm against 11.1 cm.
    """
    frames = {"p": walk_frames(1)}
    T = 10
    no_contacts = NoContacts(backend().decoder)

    def show(selector: SampleSelector) -> list[PoseOut]:
        engine = backend.engine(
            decoder=no_contacts,
            samples=20,
            lookahead=tau,
            delayed_emission=True,
            transition_frames=T,
        )
        engine.add_player("p", seed=3, selector=selector)
        return run(engine, frames)["p"]

    def steady_jumps(poses: list[PoseOut]) -> float:
        """Largest jump after 5 warm-up frames and after any transition into the sample."""
        settled = [i for i, p in enumerate(poses) if p.transitioning]
        skip = max(5, settled[-1] + 1 if settled else 0)
        return float(max_joint_jumps(positions(poses))[skip:].max())

    forced = Forced(at)
    moving = show(forced)
    assert forced.chosen is not None and forced.chosen != 0
    alone_src, alone_dst = show(Never()), show(Forced(1, forced.chosen))
    pos, src, dst = positions(moving), positions(alone_src), positions(alone_dst)
    inside = np.flatnonzero([p.transitioning for p in moving])
    assert len(inside) == T - 1
    assert np.all(np.diff(inside) == 1)
    first, last = inside[0], inside[-1] + 1  # last: the first frame of the new sample alone
    assert moving[last].sample == forced.chosen and not moving[last].transitioning
    # It starts from the old sample and ends on the new one, exactly.
    np.testing.assert_array_equal(pos[:first], src[:first])
    np.testing.assert_allclose(pos[last:], dst[last:], atol=1e-6)

    jump = max_joint_jumps(pos)[first - 1 : last].max()  # into `first` .. into `last`
    j_src, j_dst = steady_jumps(alone_src), steady_jumps(alone_dst)
    gap = np.linalg.norm(src[first - 1 : last + 1] - dst[first - 1 : last + 1], axis=-1).max()
    bound = max(j_src, j_dst) + gap / T + 0.03
    assert jump <= bound, (jump, j_src, j_dst, gap)


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
