"""Sample selectors (paper Sec. 3.2.2 and eqs. 3-4) on synthetic arrays, and swapping a
player's selector while the engine runs."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from posecast.body.ik import FLOOR_MAX_LIFT_M
from posecast.online.engine.selectors import (
    AnomalySelector,
    ObstacleSelector,
    SampleSelector,
    TargetSelector,
    choose_anomaly_rows,
    off_the_floor,
)
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import NUM_JOINTS, Joint

NO_POSES = np.zeros((5, NUM_JOINTS, 3))


def poses_with(joint: Joint, points: list[tuple[float, float, float]]) -> np.ndarray:
    """Poses ``(N, 19, 3)``: ``joint`` of sample ``i`` at ``points[i]``, all other joints
    scattered far away so that only ``joint`` can explain a choice."""
    rng = np.random.default_rng(7)
    pos = rng.uniform(-5.0, 5.0, size=(len(points), NUM_JOINTS, 3))
    pos[:, joint] = points
    return pos


# --- AnomalySelector: r = median R - min R; outlier when R_c - base > 2r -----------------
# The paper's literal rule (base 0) is the default; ``baseline="min"`` measures from min R.
LITERAL = AnomalySelector(baseline="zero")
FROM_MIN = AnomalySelector(baseline="min")


def test_anomaly_outlier_moves_to_the_best_other_sample() -> None:
    scores = np.array([0.02, 0.01, 0.03, 0.02, 0.30])  # median 0.02, min 0.01: 2r = 0.02
    assert LITERAL.choose(4, scores, NO_POSES) == 1
    assert FROM_MIN.choose(4, scores, NO_POSES) == 1  # 0.29 > 0.02 too


def test_anomaly_best_is_the_argmin_among_the_others() -> None:
    """The current sample is excluded even where it is not the worst."""
    scores = np.array([0.25, 0.5, 0.5, 0.75, 1.0])  # r = 0.25, 2r = 0.5
    assert LITERAL.choose(3, scores, NO_POSES[:5]) == 0
    assert LITERAL.choose(4, scores, NO_POSES[:5]) == 0
    assert FROM_MIN.choose(4, scores, NO_POSES[:5]) == 0  # 1.0 - 0.25 > 0.5


def test_anomaly_stays_when_not_an_outlier() -> None:
    scores = np.array([0.25, 0.5, 0.5, 0.75, 1.0])  # 2r = 0.5 exactly
    assert LITERAL.choose(1, scores, NO_POSES) is None  # R_c == 2r: not above
    assert LITERAL.choose(0, scores, NO_POSES) is None
    assert FROM_MIN.choose(3, scores, NO_POSES) is None  # 0.75 - 0.25 == 2r


def test_anomaly_factor_sets_the_threshold() -> None:
    scores = np.array([0.0, 0.25, 0.25, 0.25, 0.625])  # r = 0.25, min 0: both rules agree
    for baseline in ("min", "zero"):
        assert AnomalySelector(2.0, baseline).choose(4, scores, NO_POSES) == 0
        assert AnomalySelector(3.0, baseline).choose(4, scores, NO_POSES) is None


def test_the_default_is_the_papers_rule() -> None:
    assert AnomalySelector() == LITERAL


def test_measuring_from_min_ignores_a_tight_cluster() -> None:
    """Samples within millimetres of each other: the literal rule calls every one an
    outlier (R_c > 2r holds for all), measuring from min R calls none."""
    scores = np.array([0.100, 0.101, 0.102, 0.1025, 0.103])  # r = 0.002
    assert LITERAL.choose(0, scores, NO_POSES) == 1  # even the best sample hops away
    assert all(FROM_MIN.choose(c, scores, NO_POSES) is None for c in range(5))


def test_unknown_baseline_is_refused() -> None:
    with pytest.raises(ValueError):
        AnomalySelector(baseline="median")


def test_anomaly_with_one_sample_has_nowhere_to_go() -> None:
    assert AnomalySelector().choose(0, np.array([0.5]), NO_POSES[:1]) is None


def test_anomaly_returns_a_plain_int() -> None:
    best = AnomalySelector().choose(4, np.array([0.02, 0.01, 0.03, 0.02, 0.30]), NO_POSES)
    assert type(best) is int


def test_home_returns_to_the_mean_sample_inside_the_band() -> None:
    """``home``: away from sample 0 and not an outlier, return once sample 0 scores under
    ``home * r``; an outlier prefers sample 0 to the best sample while 0 is no outlier."""
    sel = AnomalySelector(2.0, home=1.0)
    # min 1/8, median 3/8: r = 1/4 (exact in binary); sample 0 at 1/4 <= 1.0 r: go home.
    scores = np.array([0.25, 0.125, 0.375, 0.375, 0.375])
    assert sel.choose(3, scores, NO_POSES) == 0
    assert AnomalySelector(2.0).choose(3, scores, NO_POSES) is None  # the paper stays
    # Sample 0 at 3/8 > 1.0 r but no outlier (<= 2 r): inside the band, stay.
    assert sel.choose(3, np.array([0.375, 0.125, 0.375, 0.375, 0.375]), NO_POSES) is None
    assert sel.choose(0, scores, NO_POSES) is None  # already home
    # Current sample 4 an outlier (2 > 2 r): sample 0 (3/8) is no outlier, so go there.
    out = np.array([0.375, 0.125, 0.375, 0.375, 2.0])
    assert sel.choose(4, out, NO_POSES) == 0
    assert AnomalySelector(2.0).choose(4, out, NO_POSES) == 1  # the paper: the best
    # Sample 0 an outlier too: the best other sample.
    assert sel.choose(4, np.array([2.0, 0.125, 0.375, 0.375, 2.0]), NO_POSES) == 1
    with pytest.raises(ValueError):
        AnomalySelector(2.0, home=3.0)


# --- +inf: a sample out of the pool (the engine's floor check) ------------------------


def test_samples_out_of_the_pool_neither_widen_the_spread_nor_are_chosen() -> None:
    """The estimator's median and minimum are over the pool alone: with four of seven
    samples out, the median of the rest (0.11) makes the current 0.30 an outlier, where
    counting the out samples as large errors would put the median at infinity and
    never move. The destination is the best in the pool."""
    inf = np.inf
    scores = np.array([inf, 0.11, 0.30, inf, 0.10, inf, inf])
    assert LITERAL.choose(2, scores, NO_POSES) == 4
    assert FROM_MIN.choose(2, scores, NO_POSES) == 4
    assert AnomalySelector(home=1.0).choose(2, scores, NO_POSES) == 4  # home is out
    assert FROM_MIN.choose(4, scores, NO_POSES) is None  # the best stays


def test_a_current_sample_out_of_the_pool_is_left_for_the_best() -> None:
    """Out of the pool is an outlier whatever the spread; home (sample 0) takes it when
    home is in the pool and no outlier itself."""
    scores = np.array([0.20, 0.20, 0.10, np.inf, 0.20])  # r = 0.1
    assert LITERAL.choose(3, scores, NO_POSES) == 2
    assert AnomalySelector(home=1.0).choose(3, scores, NO_POSES) == 0
    assert LITERAL.choose(0, np.full(5, np.inf), NO_POSES) is None  # no pool: stay


def test_off_the_floor_takes_samples_deeper_than_the_floor_pass_out() -> None:
    """Player 0: sample 1's feet 0.5 m under the floor (out), sample 2's 0.3 m (the floor
    pass lifts it: in). Player 1: every sample 1.5 m down, an eye-level origin: its
    scores are left as they are."""
    pos = np.zeros((2, 3, NUM_JOINTS, 3))
    pos[..., 1] = 1.0
    pos[0, 1, :, 1] -= 1.0 + FLOOR_MAX_LIFT_M + 0.1
    pos[0, 2, :, 1] -= 1.0 + FLOOR_MAX_LIFT_M - 0.1
    pos[1, :, :, 1] -= 2.5
    scores = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])
    got = off_the_floor(scores, pos)
    np.testing.assert_array_equal(got, [[0.1, np.inf, 0.3], [0.4, 0.5, 0.6]])
    np.testing.assert_array_equal(scores, [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])  # not in place


@pytest.mark.parametrize("home", [None, 0.5, 1.0])
@pytest.mark.parametrize("N", [1, 2, 5, 100])
def test_anomaly_rows_decide_each_row_as_its_selector(
    rng: np.random.Generator, N: int, home: float | None
) -> None:
    """The engine decides every AnomalySelector player in one call: row for row the same
    answer as ``choose``, for both baselines and several factors, with ties (scores on
    a coarse grid, so the median, the minimum and argmin ties all occur), a NaN row, an
    infinite score, and rows whose every other sample is infinite."""
    M = 400
    scores = rng.integers(0, 6, size=(M, N)).astype(np.float64) / 8.0
    scores[::7] = rng.uniform(0.0, 0.2, size=scores[::7].shape)
    scores[3, -1] = np.nan
    scores[5, 0] = np.inf
    current = rng.integers(0, N, size=M)
    scores[11] = np.inf
    scores[11, current[11]] = 0.5
    factor = rng.choice([0.5, 1.0, 2.0, 3.0], size=M)
    from_min = rng.uniform(size=M) < 0.5
    homes = None if home is None else np.where(rng.uniform(size=M) < 0.8, home, np.nan)
    homes = None if homes is None else np.minimum(homes, factor)
    got = choose_anomaly_rows(current, scores, factor, from_min, homes)
    want = [
        AnomalySelector(
            float(f), "min" if m else "zero", None if homes is None or np.isnan(h) else float(h)
        ).choose(int(c), row, NO_POSES)
        for c, row, f, m, h in zip(
            current, scores, factor, from_min, [np.nan] * M if homes is None else homes, strict=True
        )
    ]
    assert got.tolist() == [-1 if w is None else w for w in want]
    if N > 2:
        assert (got >= 0).sum() > 10  # the rule does fire: this compares decisions


# --- TargetSelector (eq. 3): argmin distance of a joint to a target, with a margin -------


TARGET = (0.0, 1.5, 0.5)


def at_distances(d: list[float], joint: Joint = Joint.RIGHT_HAND) -> np.ndarray:
    """Poses whose ``joint`` lies ``d[i]`` metres straight above :data:`TARGET`."""
    return poses_with(joint, [(TARGET[0], TARGET[1] + di, TARGET[2]) for di in d])


def test_target_picks_the_closest_sample() -> None:
    sel = TargetSelector(Joint.RIGHT_HAND, TARGET, margin_m=0.02)
    pos = at_distances([0.30, 0.10, 0.29, 0.50])
    np.testing.assert_allclose(sel.distances(pos), [0.30, 0.10, 0.29, 0.50], atol=1e-12)
    assert sel.choose(0, np.zeros(4), pos) == 1
    assert sel.choose(3, np.zeros(4), pos) == 1
    assert sel.choose(1, np.zeros(4), pos) is None  # already the closest


def test_target_margin_is_hysteresis() -> None:
    """A sample closer by less than the margin does not win; by more than it, it does."""
    pos = at_distances([0.30, 0.29, 0.40])
    assert (
        TargetSelector(Joint.RIGHT_HAND, TARGET, margin_m=0.02).choose(0, np.zeros(3), pos) is None
    )
    assert TargetSelector(Joint.RIGHT_HAND, TARGET, margin_m=0.005).choose(0, np.zeros(3), pos) == 1


def test_target_looks_only_at_its_joint() -> None:
    pos = at_distances([0.30, 0.10], joint=Joint.LEFT_FOOT)
    pos[:, Joint.RIGHT_HAND] = [[0.0, 1.5, 0.5], [9.0, 9.0, 9.0]]  # hand of 0 on target
    assert TargetSelector(Joint.LEFT_FOOT, TARGET).choose(0, np.zeros(2), pos) == 1
    assert TargetSelector(Joint.RIGHT_HAND, TARGET).choose(1, np.zeros(2), pos) == 0


def test_target_ignores_anomaly_scores() -> None:
    pos = at_distances([0.30, 0.10])
    sel = TargetSelector(Joint.RIGHT_HAND, TARGET)
    assert sel.choose(0, np.array([0.0, 10.0]), pos) == 1


# --- ObstacleSelector (eq. 4): argmax distance, only once inside the radius ---------------


OBSTACLE = (1.0, 0.5, 0.0)


def from_obstacle(d: list[float]) -> np.ndarray:
    return poses_with(Joint.LEFT_FOOT, [(OBSTACLE[0] - di, OBSTACLE[1], OBSTACLE[2]) for di in d])


def test_obstacle_stays_while_outside_the_radius() -> None:
    sel = ObstacleSelector(Joint.LEFT_FOOT, OBSTACLE, radius_m=0.25)
    assert sel.choose(0, np.zeros(3), from_obstacle([0.30, 0.90, 0.50])) is None
    assert sel.choose(0, np.zeros(3), from_obstacle([0.25, 0.90, 0.50])) is None  # on the edge


def test_obstacle_inside_the_radius_moves_to_the_farthest() -> None:
    sel = ObstacleSelector(Joint.LEFT_FOOT, OBSTACLE, radius_m=0.25)
    pos = from_obstacle([0.10, 0.90, 0.50, 0.05])
    np.testing.assert_allclose(sel.distances(pos), [0.10, 0.90, 0.50, 0.05], atol=1e-12)
    assert sel.choose(0, np.zeros(4), pos) == 1
    assert sel.choose(3, np.zeros(4), pos) == 1


def test_obstacle_inside_the_radius_but_already_farthest_stays() -> None:
    sel = ObstacleSelector(Joint.LEFT_FOOT, OBSTACLE, radius_m=0.25)
    assert sel.choose(1, np.zeros(3), from_obstacle([0.10, 0.20, 0.05])) is None


@pytest.mark.parametrize(
    "selector",
    [AnomalySelector(), TargetSelector(Joint.HEAD, TARGET), ObstacleSelector(Joint.HEAD, OBSTACLE)],
)
def test_selectors_are_immutable_values(selector: SampleSelector) -> None:
    with pytest.raises(AttributeError):
        selector.factor = 1.0  # type: ignore[attr-defined]


# --- swapping a player's selector at run time ---------------------------------------------


class Never:
    """Always stay: keeps a player on its first sample while the test sets things up."""

    def choose(self, current: int, scores: np.ndarray, positions: np.ndarray) -> int | None:
        return None


class Recording:
    """Wraps a selector and keeps every call and answer."""

    def __init__(self, inner: SampleSelector) -> None:
        self.inner = inner
        self.calls: list[tuple[int, np.ndarray, np.ndarray, int | None]] = []

    def choose(self, current: int, scores: np.ndarray, positions: np.ndarray) -> int | None:
        best = self.inner.choose(current, scores, positions)
        self.calls.append((current, scores.copy(), np.array(positions), best))
        return best


def test_set_selector_takes_effect_for_that_player_only(
    make_engine: Callable[..., Engine], walk_frames: Callable[..., list[TrackerFrame]]
) -> None:
    """Two players on the same walk and seed, both held on sample 0. At tick 15 player
    ``a`` gets a target selector whose target is where sample 7's left foot is on that
    tick (found by a first, identical run). From that very tick the engine asks it,
    with ``(N,)`` scores and ``(N, 19, 3)`` poses, and moves ``a`` to sample 7. Player
    ``b`` is untouched. Swapping ``a`` back to a selector that never moves ends its
    transitions."""
    N = 10
    frames = walk_frames(2)

    def play(selector: SampleSelector, ticks: int) -> Engine:
        engine = make_engine(samples=N, lookahead=3, delayed_emission=True)
        engine.add_player("a", seed=5, selector=Never())
        engine.add_player("b", seed=5, selector=Never())
        for i, frame in enumerate(frames[:ticks]):
            if i == 15:
                engine.set_selector("a", selector)
            if i == 30:
                engine.set_selector("a", Never())
            engine.push("a", frame)
            engine.push("b", frame)
            engine.tick()
        return engine

    probe = Recording(Never())
    play(probe, 16)
    current, scores, positions, best = probe.calls[0]
    assert (current, best) == (0, None)
    assert scores.shape == (N,)
    assert positions.shape == (N, NUM_JOINTS, 3)
    target_m = tuple(float(v) for v in positions[7, Joint.LEFT_FOOT])

    target = Recording(TargetSelector(Joint.LEFT_FOOT, target_m, margin_m=0.0))  # type: ignore[arg-type]
    engine = play(target, 16)
    assert [(c[0], c[3]) for c in target.calls] == [(0, 7)]
    np.testing.assert_array_equal(target.calls[0][2], positions)
    assert engine.current_sample("a") == 7
    assert (engine.transitions("a"), engine.transitions("b")) == (1, 0)

    # Over 60 ticks: every transition of ``a`` is one the target selector asked for
    # (ticks 15-29); after the swap back at tick 30 there are none.
    target = Recording(target.inner)
    engine = play(target, 60)
    assert engine.transitions("a") == sum(c[3] is not None for c in target.calls) >= 1
    assert all(c[1].shape == (N,) for c in target.calls)
    assert engine.current_sample("b") == 0
    assert engine.transitions("b") == 0
