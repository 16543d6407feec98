"""The batched look-ahead SSI engine (paper Sec. 3.2): determinism and outlier-triggered
transitions to the best sample (smoothness, the floor). Frames, look-ahead, batching,
membership, missing frames and calibration: test_ssi_frames.py."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from posecast.online.engine.ports import Pool
from posecast.online.engine.selectors import AnomalySelector, SampleSelector
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import PoseOut, TrackerFrame
from posecast.skeleton import NUM_JOINTS
from tests.online.engine.conftest import BackendLoader
from tests.online.engine.ssi_helpers import (
    Forced,
    MakeEngine,
    Never,
    NoContacts,
    RecordingPool,
    WalkFrames,
    assert_same_poses,
    max_joint_jumps,
    positions,
    run,
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
