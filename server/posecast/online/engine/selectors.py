"""Sample selectors: which latent sample to show (paper Sec. 3.2.2, 3.2.5, 5.3).

A selector looks at every sample of one player at one frame and answers whether the
current sample should be left, and for which. Each is a small pure class; the engine
asks the player's selector once per frame, and a selector can be swapped at any time.

* :class:`AnomalySelector` (default): trimmed estimator on the anomaly error ``R``;
  with ``r = median(R) - min(R)``, the current sample is an outlier when
  ``R_c > k * r`` as the paper writes it (default, ``baseline="zero"``), or, measured
  from the best sample, ``R_c - min(R) > k * r`` (``baseline="min"``); the best is
  ``argmin R`` among the others.

The two rules: ``R_c > 2r`` compares an absolute error with a spread, so when the
samples agree closely (``min R > 2/3 median R``) every sample, the best included, is an
"outlier"; ``R_c - min R > 2r`` is scale-free. Measured on the validation split
(``docs/evaluation.md``), the paper's rule cut the implausible-frame rate from 0.6 %
to 0.1 % at 7.9 transitions a minute, while the scale-free rule at factor 2 never
fired and at factor 1 needed 23.7 transitions a minute for the same rate, so the
paper's rule is the default.
A score of ``+inf`` takes a sample out of the anomaly selector's pool for that frame:
the engine marks so every sample whose feet sink deeper than the floor pass lifts
(:func:`off_the_floor`); the position selectors below do not read scores.

* :class:`TargetSelector` (eq. 3): ``argmin`` distance from an end effector to a target.
* :class:`ObstacleSelector` (eq. 4): ``argmax`` distance from a joint to an obstacle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.ik import sunk
from posecast.skeleton import Joint

F64 = NDArray[np.floating]


class SampleSelector(Protocol):
    """A player's sample-selection policy (not the wire ``selector`` message, which
    :mod:`posecast.online.core.session` turns into one of these)."""

    def choose(self, current: int, scores: F64, positions: F64) -> int | None:
        """Return the sample to move to, or ``None`` to stay.

        Args:
            current: index of the sample shown now.
            scores: ``(N,)`` anomaly errors ``R`` (metres) of every sample; ``+inf``
                marks a sample out of the pool this frame (the engine's floor check:
                feet deeper below the floor than the floor pass lifts), which
                :class:`AnomalySelector` never moves to and leaves when it is the
                current one. The selectors that judge positions alone
                (:class:`TargetSelector`, :class:`ObstacleSelector`) do not read
                scores and may pick such a sample.
            positions: ``(N, 19, 3)`` post-IK world positions of every sample.
        """
        ...


@dataclass(frozen=True)
class AnomalySelector:
    """The trimmed estimator. ``home`` (``None``: off, the paper) makes sample 0, the
    prior's mean (``eps = 0``, the network's single best guess), the resting place:
    a player away from it returns when sample 0 scores at most ``home * r`` (measured
    like the outlier rule), and an outlier moves to sample 0 rather than to the best
    sample whenever sample 0 is not an outlier itself. With ``home < factor`` the two
    thresholds form a hysteresis band, so a player does not flap between them."""

    factor: float = 2.0
    baseline: str = "zero"  # "zero": R_c > k r (the paper);  "min": R_c - min R > k r
    home: float | None = None

    def __post_init__(self) -> None:
        if self.baseline not in ("min", "zero"):
            raise ValueError(f"baseline must be 'min' or 'zero', not {self.baseline!r}")
        if self.home is not None and not 0.0 <= self.home <= self.factor:
            raise ValueError("home must be within [0, factor]")

    def choose(self, current: int, scores: F64, positions: F64) -> int | None:
        pool = scores[scores != np.inf]  # +inf: out of the pool (SampleSelector.choose)
        if not len(pool):
            return None
        low = float(np.min(pool))
        r = float(np.median(pool)) - low
        base = low if self.baseline == "min" else 0.0
        zero_ok = self.home is not None and not scores[0] - base > self.factor * r
        if not scores[current] - base > self.factor * r:
            if self.home is not None and current != 0 and scores[0] - base <= self.home * r:
                return 0
            return None
        if zero_ok and current != 0:
            return 0
        others = scores.copy()
        others[current] = np.inf
        best = int(np.argmin(others))
        return best if np.isfinite(others[best]) else None


def choose_anomaly_rows(
    current: NDArray[np.intp],
    scores: NDArray[np.float64],
    factor: F64,
    from_min: NDArray[np.bool_],
    home: F64 | None = None,
) -> NDArray[np.intp]:
    """:meth:`AnomalySelector.choose` for ``M`` players at once: the sample each moves to,
    ``-1`` to stay.

    ``current (M,)``, ``scores (M, N)`` float64, and per player its selector's
    ``factor (M,)``, ``from_min (M,)`` (``baseline == "min"``) and ``home (M,)`` (NaN for
    ``None``; ``None`` for all off). Row ``i`` gives exactly what
    ``AnomalySelector(factor[i], ...).choose(current[i], scores[i], _)`` gives: the same
    float64 operations, a NaN anywhere in a row never moves, and ties go to the lowest
    index (``argmin`` with the current sample excluded).
    """
    rows = np.arange(len(scores))
    # The estimator's median and minimum are over each row's pool: +inf is out of it.
    out = scores == np.inf
    if out.any():
        # Sorted, a row's k pool scores come first: its median is the mean of the
        # middle two of them (np.median's arithmetic). A row with a NaN, or with no
        # pool, never moves (NaN low and r).
        k = scores.shape[1] - out.sum(axis=1)  # (M,)
        ranked = np.sort(scores, axis=1)  # NaN sorts last, after +inf
        mid = np.maximum(k, 1)
        med = 0.5 * (ranked[rows, (mid - 1) // 2] + ranked[rows, mid // 2])
        low = ranked[:, 0].copy()
        low[(k == 0) | np.isnan(scores).any(axis=1)] = np.nan
    else:  # NaN anywhere in a row makes its low and median NaN: it never moves
        low, med = scores.min(axis=1), np.median(scores, axis=1)
    with np.errstate(invalid="ignore"):
        r = med - low
        base = np.where(from_min, low, 0.0)
        outlier = scores[rows, current] - base > factor * r
        zero_out = scores[:, 0] - base > factor * r
    others = scores.copy()
    others[rows, current] = np.inf
    best = np.argmin(others, axis=1)
    move = outlier & np.isfinite(others[rows, best])
    chosen = np.where(move, best, -1)
    if home is None:
        return chosen
    on = ~np.isnan(home)
    away = current != 0
    with np.errstate(invalid="ignore"):
        zero_ok = on & ~zero_out & ~np.isnan(r)  # NaN rows never move
        back = on & away & ~outlier & (scores[:, 0] - base <= home * r)
    to_zero = (outlier & zero_ok & away) | back
    return np.where(to_zero, 0, chosen)


def off_the_floor(scores: F64, positions: F64) -> F64:
    """``scores (P, N)`` with ``+inf`` (out of the pool, :meth:`SampleSelector.choose`) for
    each sample whose post-IK pose ``positions (P, N, 19, 3)`` has a foot deeper below
    the floor than the floor pass lifts (:func:`~posecast.body.ik.sunk`). A
    player whose every sample is that deep (a tracking space whose origin is not on the
    floor) keeps its scores: the floor says nothing about which of them is better."""
    deep = sunk(positions)  # (P, N)
    deep &= ~deep.all(axis=1, keepdims=True)
    out: F64 = np.where(deep, np.inf, scores) if deep.any() else scores
    return out


@dataclass(frozen=True)
class DefaultSelector:
    """A request for the engine's own :class:`AnomalySelector` (its configured
    baseline and ``home``), with ``factor`` in place of the configured one where
    given: what a backend's ``selector`` of kind ``anomaly`` asks for.
    :meth:`~posecast.online.engine.ssi.Engine.set_selector` resolves it; it never
    chooses itself."""

    factor: float | None = None

    def choose(self, current: int, scores: F64, positions: F64) -> int | None:
        raise TypeError("DefaultSelector is resolved by Engine.set_selector")


@dataclass(frozen=True)
class TargetSelector:
    """Hit ``target_m`` (world, metres) with ``joint``; switch when another sample is
    closer by more than ``margin_m`` (hysteresis, so near-ties don't flap)."""

    joint: Joint
    target_m: tuple[float, float, float]
    margin_m: float = 0.02

    def distances(self, positions: F64) -> F64:
        d: F64 = np.linalg.norm(positions[:, self.joint] - np.asarray(self.target_m), axis=-1)
        return d

    def choose(self, current: int, scores: F64, positions: F64) -> int | None:
        d = self.distances(positions)
        best = int(np.argmin(d))
        return best if best != current and d[current] - d[best] > self.margin_m else None


@dataclass(frozen=True)
class ObstacleSelector:
    """Keep ``joint`` away from ``obstacle_m``: when the current sample comes within
    ``radius_m``, move to the sample whose joint is farthest from it."""

    joint: Joint
    obstacle_m: tuple[float, float, float]
    radius_m: float = 0.2

    def distances(self, positions: F64) -> F64:
        d: F64 = np.linalg.norm(positions[:, self.joint] - np.asarray(self.obstacle_m), axis=-1)
        return d

    def choose(self, current: int, scores: F64, positions: F64) -> int | None:
        d = self.distances(positions)
        if d[current] >= self.radius_m:
            return None
        best = int(np.argmax(d))
        return best if best != current else None
