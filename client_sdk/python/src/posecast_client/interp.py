"""Interpolation: a jitter buffer per player, sampled at any display rate. Pure: the
caller passes every time, nothing here reads a clock.

Poses arrive at uneven moments (network jitter, a lost pose, a burst after a stall),
but each carries the server time ``t`` of the tick that made it. A
:class:`PoseBuffer` keeps a player's recent poses ordered by ``t`` and shows them a
render delay late, on the server's timeline, so arrival jitter up to the delay never
shows. The delay adapts (``adaptive``, the default): it follows the jitter the buffer
measures, the smallest delay at which 99 % of the recent pose intervals interpolate,
within ``min_delay_s`` to ``max_delay_s``, changing by at most 5 % of real time
(:mod:`posecast_client.render_delay`); ``adaptive=False`` keeps it at ``delay_s``::

    buffers = pc.Interpolator()                       # one PoseBuffer per player
    async for event in client.events():
        buffers.feed(event)                           # poses, leaves, welcomes
    ...
    now = client.clock.display_time(time.monotonic())  # each rendered frame
    for player, shown in buffers.poses_at(now).items():
        draw(player, shown.positions, shown.rotations)

The query time is the display clock (:meth:`ClockSync.display_time`), not
``to_server``: the clock estimate steps by up to tens of ms when its best ping leaves
the window, and the display clock slews such steps instead of popping every avatar.

At query time ``time``, the buffer shows ``tau = time - delay``
(:attr:`PoseBuffer.delay_s`). With ``a`` the newest pose at or before ``tau`` and
``b`` the one after it:

1. **interpolate**: positions lerp and rotations slerp (shortest arc, so ``q`` and
   ``-q`` give the same result) from ``a`` to ``b``.
2. **snap**: ``b`` starts a new segment when its pelvis moved more than
   ``teleport_m`` from ``a`` (a teleport), when it follows ``a`` by more than
   ``gap_s`` (a stall or a rejoin), or when it was pushed as a ``keyframe`` and its
   ``seq`` is not newer than ``a``'s (a new sequence: the player rejoined). A forward
   ``seq`` gap is no snap: a pose rate below 60 Hz, a sender faster than 60 Hz or a
   skipped pose steps it by more than 1 while the motion goes on. Nothing is
   blended across a segment start: until ``tau`` reaches ``b.t``, ``a`` is shown as
   if it were the newest pose (rule 3), so what is on screen does not depend on
   whether ``b`` has arrived yet; from ``b.t`` on, ``b``.
3. **extrapolate**: past the newest pose, ``a`` moves on at the velocity from its
   predecessor (positions linearly, rotations along the same great circle) for at
   most ``max_extrapolate_s``, then **holds** there (no jump when the bound is hit).
4. **hold**: before the first pose, and from a pose with no predecessor in its
   segment, that pose is shown as it is.
5. **correct smoothly**: :meth:`PoseBuffer.pose_at` remembers what it showed last.
   When poses that arrived since then change that answer (a burst of lost poses ran
   past the buffer, rule 3 guessed, and the late poses now say otherwise), the
   difference is added back and fades as ``exp(-dt / correction_s)``, so a wrong
   guess costs no step. A segment start (rule 2) between the two frames, time going
   back, or a pause longer than ``gap_s`` shows the new answer at once.

Memory is bounded: ``capacity`` poses per player (the oldest go first) and
``max_players`` buffers in an :class:`Interpolator` (the player heard from least
recently goes first). Arrays are ``float64``: positions ``(J, 3)`` metres, rotations
``(J, 4)`` xyzw (renormalised on the way out), ``J`` = 19 in joint order for posecast
poses; a pose without rotations gives samples without rotations.
"""

from __future__ import annotations

import bisect
import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from posecast_client.protocol import Pose, Presence, Welcome, seq_delta
from posecast_client.render_delay import RenderDelay
from posecast_client.rotations import quat_mul
from posecast_client.sampling import (
    ROOT,
    Correction,
    Entry,
    Mode,
    SamplePlan,
    fade,
    make_samples,
)
from posecast_client.sampling import quat_slerp as quat_slerp  # part of this module's API

F64 = NDArray[np.float64]
_CONJ = np.array([-1.0, -1.0, -1.0, 1.0])  # q * _CONJ is q's inverse, for unit q


class PoseLike(Protocol):
    """What a buffer reads from a pose: :class:`~posecast_client.protocol.Pose` fits."""

    @property
    def player(self) -> str: ...
    @property
    def seq(self) -> int: ...
    @property
    def t(self) -> float: ...
    @property
    def positions(self) -> F64: ...
    @property
    def rotations(self) -> F64 | None: ...


@dataclass(frozen=True, slots=True)
class InterpConfig:
    """How a :class:`PoseBuffer` smooths; validated once, shared by every buffer.

    Args:
        adaptive: the render delay follows the measured arrival jitter (True, see
            :mod:`posecast_client.render_delay`); False: it stays ``delay_s``.
        delay_s: the fixed render delay, seconds behind the query time (0.1), and the
            adaptive delay's start (clamped to its bounds). Fixed, jitter up to
            ``delay_s`` minus the pose interval never shows; each lost pose in a row
            costs one pose interval of that margin.
        min_delay_s: the adaptive delay's lower bound (0.02 s: a bit above one 60 Hz
            pose interval).
        max_delay_s: its upper bound (0.25 s); a link worse than that extrapolates.
        delay_quantile: the share of recent pose intervals the adaptive delay lets
            interpolate whole (0.99, nearest rank).
        delay_window: the recent poses it measures (256: about 4 s at 60 Hz).
        delay_margin_s: added to that quantile (0.002 s).
        delay_slew: the most the adaptive delay changes per second of query time
            (0.05: the shown time runs at 0.95 to 1.05 of real speed).
        max_extrapolate_s: the longest time a pose is carried on at its velocity past
            the newest one before it holds (0.1).
        teleport_m: a pelvis jump between consecutive poses beyond this snaps (1.0 m).
        gap_s: consecutive poses further apart than this snap (0.25 s); nor do they
            count toward the adaptive delay.
        capacity: poses kept per player (32: a 0.5 s delay at 60 Hz).
        correction_s: time constant over which a correction fades out (0.05 s):
            when poses that arrived late change what was already shown, the shown
            pose approaches the new one as ``exp(-dt / correction_s)``; 0 shows each
            correction at once.
    """

    delay_s: float = 0.1
    max_extrapolate_s: float = 0.1
    teleport_m: float = 1.0
    gap_s: float = 0.25
    capacity: int = 32
    correction_s: float = 0.05
    adaptive: bool = True
    min_delay_s: float = 0.02
    max_delay_s: float = 0.25
    delay_quantile: float = 0.99
    delay_window: int = 256
    delay_margin_s: float = 0.002
    delay_slew: float = 0.05

    def __post_init__(self) -> None:
        for name in (
            "delay_s",
            "max_extrapolate_s",
            "correction_s",
            "min_delay_s",
            "max_delay_s",
            "delay_margin_s",
            "delay_slew",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")
        for name in ("teleport_m", "gap_s"):
            v = getattr(self, name)
            if not v > 0.0:  # inf allowed: never snap on that rule
                raise ValueError(f"{name} must be > 0, got {v}")
        if self.capacity < 2:
            raise ValueError(f"capacity must be >= 2, got {self.capacity}")
        if self.min_delay_s > self.max_delay_s:
            raise ValueError(f"min_delay_s {self.min_delay_s} > max_delay_s {self.max_delay_s}")
        if not 0.0 < self.delay_quantile <= 1.0:
            raise ValueError(f"delay_quantile must be in (0, 1], got {self.delay_quantile}")
        if self.delay_window < 1:
            raise ValueError(f"delay_window must be >= 1, got {self.delay_window}")


DEFAULT_INTERP = InterpConfig()


@dataclass(frozen=True, slots=True)
class InterpolatedPose:
    """One player's pose as shown at ``t`` (the query time minus the delay)."""

    player: str
    t: float  # server time shown, seconds
    seq: int  # seq of the received pose at or before t (the first one while holding it)
    positions: F64  # (J, 3) world metres
    rotations: F64 | None  # (J, 4) world xyzw, unit; None when the poses had none
    mode: Mode


class PoseBuffer:
    """The jitter buffer of one player (see the module docstring for the rules).

    Args:
        config: delay, extrapolation bound, snap thresholds and capacity
            (:data:`DEFAULT_INTERP`).
    """

    def __init__(self, config: InterpConfig = DEFAULT_INTERP) -> None:
        self.config = config
        self.player: str | None = None
        self._entries: list[Entry] = []  # sorted by t, no two with the same t
        self._times: list[float] = []  # the entries' t, for bisect
        self._last: InterpolatedPose | None = None  # what pose_at showed last
        self._last_plan: SamplePlan | None = None  # the plan of its raw sample
        self._offset: Correction | None = None  # the correction it added to that sample
        self._unseen = 0  # entries pushed since the last pose_at
        self._delay = RenderDelay(
            start_s=config.delay_s,
            min_s=config.min_delay_s,
            max_s=config.max_delay_s,
            quantile=config.delay_quantile,
            window=config.delay_window,
            margin_s=config.delay_margin_s,
            slew=config.delay_slew,
        )

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def delay_s(self) -> float:
        """The render delay now, seconds: ``config.delay_s`` when not adaptive."""
        return self._delay.delay_s if self.config.adaptive else self.config.delay_s

    @property
    def target_delay_s(self) -> float | None:
        """The delay the adaptive delay moves toward (``None`` before it measured a
        pose interval, and when not adaptive)."""
        return self._delay.target_s if self.config.adaptive else None

    @property
    def shown_t(self) -> float | None:
        """The server time the last :meth:`pose_at` showed (its ``tau``), ``None``
        before it showed a pose. A received pose is first on screen at the first
        frame whose ``shown_t`` reaches its ``t``."""
        return None if self._last is None else self._last.t

    @property
    def newest_t(self) -> float | None:
        """Server time of the newest pose kept (``None`` while empty)."""
        return self._times[-1] if self._times else None

    def push(self, pose: PoseLike, *, keyframe: bool = False) -> bool:
        """Keep ``pose``; ``False`` when it was dropped: a duplicate of a kept ``t``, a
        non-finite ``t``, or older than everything kept while the buffer is full.

        ``keyframe``: the pose is a resync point (a v2 keyframe); when its ``seq`` is
        not newer than its predecessor's (a new sequence) it snaps instead of being
        blended into.
        """
        t = float(pose.t)
        if not math.isfinite(t):
            return False
        i = bisect.bisect_left(self._times, t)
        if i < len(self._times) and self._times[i] == t:
            return False
        if i == 0 and len(self._entries) >= self.config.capacity:
            return False
        rot = None if pose.rotations is None else np.array(pose.rotations, dtype=np.float64)
        pos = np.array(pose.positions, dtype=np.float64)
        entry = Entry(t, int(pose.seq), keyframe, pos, rot, root=tuple(pos[ROOT].tolist()))
        self.player = pose.player
        self._entries.insert(i, entry)
        self._times.insert(i, t)
        # Rule 2 depends only on an entry and the one before it: decided once here,
        # for the new entry and for the one after it (whose predecessor it now is).
        if i > 0:
            entry.snaps = self._snap_rule(self._entries[i - 1], entry)
        if i + 1 < len(self._entries):
            after = self._entries[i + 1]
            after.snaps = self._snap_rule(entry, after)
        self._unseen += 1
        if len(self._entries) > self.config.capacity:
            self._unseen -= not self._entries[0].seen
            del self._entries[0], self._times[0]
        return True

    def clear(self) -> None:
        """Forget every pose (after a reconnect: the server's clock may have changed)."""
        self._entries.clear()
        self._times.clear()
        self._last = self._last_plan = self._offset = None
        self._unseen = 0
        self._delay.reset()

    def pose_at(self, time: float) -> InterpolatedPose | None:
        """The pose shown at server time ``time`` (``time - delay_s`` on the poses'
        timeline), or ``None`` before the first pose arrived.

        Call it once per displayed frame, with times that do not go back: where poses
        that arrived since the last call change what that call showed (a late pose
        replacing an extrapolation), the difference fades out over ``correction_s``
        instead of showing as one step (rule 5). :meth:`sample_at` is the same sample
        without that memory.

        Adaptive, each call first counts the poses pushed since the last one as
        arrived at ``time`` and moves the delay (:mod:`posecast_client.render_delay`).
        :meth:`Interpolator.poses_at` does the same for every player in one batch.
        """
        plan = self._begin(time)
        if plan is None:
            return None
        pos, rot = make_samples([plan])[0]
        return self._finish(plan, pos, rot)

    def advance(self, time: float) -> float | None:
        """A display frame at ``time`` that does not draw this player (off screen,
        culled): the adaptive delay moves exactly as :meth:`pose_at` would move it,
        and nothing is sampled. Returns the server time that frame would show
        (``time - delay_s``, what :attr:`shown_t` would be), ``None`` while empty.
        The next :meth:`pose_at` starts afresh: no correction carries over a frame
        that was not drawn."""
        plan = self._begin(time)
        self._last = self._last_plan = self._offset = None
        return None if plan is None else plan.tau

    def sample_at(self, time: float) -> InterpolatedPose | None:
        """The pose at server time ``time`` from the poses kept now, rules 1 to 4 only
        (no memory of earlier calls), at the current :attr:`delay_s` (which only
        :meth:`pose_at` moves)."""
        plan = self._plan(time - self.delay_s)
        return None if plan is None else self._raw(plan)

    def _begin(self, time: float) -> SamplePlan | None:
        """A display frame at ``time``, up to the arrays: the adaptive delay's step and
        the plan of the raw sample (rules 1 to 4); ``None`` while empty."""
        if self.config.adaptive:
            self._observe(time)
            self._delay.advance(time)
        plan = self._plan(time - self.delay_s)
        if plan is None:
            self._last = self._last_plan = self._offset = None
        return plan

    def _finish(self, plan: SamplePlan, pos: F64, rot: F64 | None) -> InterpolatedPose:
        """The frame's shown pose from its raw sample (``plan``'s ``pos``, ``rot``):
        rule 5's correction, and the memory of what was shown (one buffer's
        :func:`_finish_all`)."""
        return _finish_all([(self, plan, pos, rot)])[0]

    def _raw_pose(self, plan: SamplePlan, pos: F64, rot: F64 | None) -> InterpolatedPose:
        return InterpolatedPose(self.player or "", plan.tau, plan.base.seq, pos, rot, plan.mode)

    def _fading(self, plan: SamplePlan) -> tuple[Correction, float] | None:
        """Rule 5 for a frame at ``plan.tau``: what the last frame showed beyond what it
        would show with today's poses (an offset), and the share of it left now, ``k``;
        ``None`` when nothing is to be corrected.

        The last frame's plan unchanged (no pose arrived that changes its sample), that
        offset is the one the last frame added (none when it showed its sample as it
        was); otherwise it is made afresh from what the last frame showed."""
        last, last_plan = self._last, self._last_plan
        if last is None or last_plan is None or not self._blends(last.t, plan.tau):
            self._offset = None
            return None
        before_plan = self._plan(last.t)
        assert before_plan is not None
        if before_plan.same(last_plan):
            prev = self._offset
            if prev is None:
                return None
        else:
            before = self._raw(before_plan)
            turn = None
            if last.rotations is not None and before.rotations is not None:
                turn = quat_mul(last.rotations, before.rotations * _CONJ)  # (J, 4) world delta
            prev = Correction(last.positions - before.positions, turn)
        return prev, math.exp(-(plan.tau - last.t) / self.config.correction_s)

    def _observe(self, time: float) -> None:
        """Each pose pushed since the last query arrived, for the display, at ``time``:
        its need is ``time`` minus its predecessor's ``t``. Not counted: a pose
        without a predecessor or after a gap beyond ``gap_s``, and every pose when the
        last query is not just before ``time`` (:meth:`RenderDelay.measures`)."""
        if self._unseen == 0:
            return
        gap = self.config.gap_s
        measures = self._delay.measures(time, gap)
        for k, e in enumerate(self._entries):
            if e.seen:
                continue
            e.seen = True
            if measures and k > 0 and e.t - self._times[k - 1] <= gap:
                self._delay.observe(time - self._times[k - 1])
        self._unseen = 0

    def _blends(self, last_tau: float, tau: float) -> bool:
        """Whether a correction since the frame at ``last_tau`` fades (rule 5): time
        moved on, by less than ``gap_s``, and no segment starts in between."""
        if self.config.correction_s == 0.0 or not 0.0 < tau - last_tau <= self.config.gap_s:
            return False
        lo = bisect.bisect_right(self._times, last_tau)
        hi = bisect.bisect_right(self._times, tau)
        return not any(self._entries[k].snaps for k in range(max(lo, 1), hi))

    def _plan(self, tau: float) -> SamplePlan | None:
        """Rules 1 to 4 at ``tau`` on the poses' timeline, as a plan (no arrays)."""
        if not self._entries:
            return None
        i = bisect.bisect_right(self._times, tau) - 1  # a = entries[i]: newest at or before tau
        if i < 0:
            return self._hold(self._entries[0], tau)
        a = self._entries[i]
        if i + 1 < len(self._entries):
            b = self._entries[i + 1]
            if not b.snaps:
                u = (tau - a.t) / (b.t - a.t)
                rot = a.rotations is not None and b.rotations is not None
                q0, q1 = (a, b) if rot else (None, None)
                return SamplePlan(tau, a, b, a, u, q0, q1, u, "interpolate")
        # a is the newest pose of its segment: carry it on, then hold.
        p = self._entries[i - 1] if i > 0 else None
        if p is None or a.snaps or self.config.max_extrapolate_s == 0.0:
            return self._hold(a, tau)
        ahead = tau - a.t
        mode: Mode = "extrapolate" if ahead <= self.config.max_extrapolate_s else "hold"
        s = min(ahead, self.config.max_extrapolate_s) / (a.t - p.t)
        rotated = a.rotations is not None and p.rotations is not None
        return SamplePlan(
            tau, a, a, p, s, p if rotated else None, a if rotated else None, 1.0 + s, mode
        )

    def _snap_rule(self, a: Entry, b: Entry) -> bool:
        """Whether ``b`` starts a new segment after ``a`` (rule 2)."""
        cfg = self.config
        if b.t - a.t > cfg.gap_s:
            return True
        if b.keyframe and seq_delta(b.seq, a.seq) <= 0:
            return True
        return math.dist(b.root, a.root) > cfg.teleport_m

    def _hold(self, a: Entry, tau: float) -> SamplePlan:
        q = a if a.rotations is not None else None
        return SamplePlan(tau, a, a, a, 0.0, q, q, 0.0, "hold")

    def _raw(self, plan: SamplePlan) -> InterpolatedPose:
        pos, rot = make_samples([plan])[0]
        return self._raw_pose(plan, pos, rot)


def _finish_all(
    frames: list[tuple[PoseBuffer, SamplePlan, F64, F64 | None]],
) -> list[InterpolatedPose]:
    """Each buffer's shown pose from its raw sample: rule 5's fading corrections of
    every buffer that has one (in batches, :func:`fade`), and each buffer's memory of
    what it showed."""
    shown = [buf._raw_pose(plan, pos, rot) for buf, plan, pos, rot in frames]
    pending = []
    for n, (buf, plan, _, rot) in enumerate(frames):
        got = buf._fading(plan)
        if got is not None:
            pending.append((n, *got, rot))
    corrections: list[Correction | None] = [None] * len(frames)
    for (n, _, _, _), faded in zip(pending, fade([p[1:] for p in pending]), strict=True):
        if faded is None:  # faded out: show (and remember) the raw sample
            continue
        corrections[n], rot = faded
        raw = shown[n]
        shown[n] = InterpolatedPose(raw.player, raw.t, raw.seq, raw.positions + faded[0].dpos,
                                    raw.rotations if rot is None else rot, raw.mode)  # fmt: skip
    for n, (buf, plan, _, _) in enumerate(frames):
        buf._last, buf._last_plan, buf._offset = shown[n], plan, corrections[n]
    return shown


class Interpolator:
    """A :class:`PoseBuffer` per player, created on a player's first pose.

    Args:
        config: shared by every buffer (:data:`DEFAULT_INTERP`).
        max_players: buffers kept at most (512); past it, the player whose last pose
            is the oldest arrival is forgotten.
    """

    def __init__(self, config: InterpConfig = DEFAULT_INTERP, *, max_players: int = 512) -> None:
        if max_players < 1:
            raise ValueError("max_players must be >= 1")
        self.config = config
        self.max_players = max_players
        self._buffers: OrderedDict[str, PoseBuffer] = OrderedDict()

    @property
    def players(self) -> tuple[str, ...]:
        return tuple(self._buffers)

    def buffer(self, player: str) -> PoseBuffer | None:
        return self._buffers.get(player)

    def push(self, pose: PoseLike, *, keyframe: bool = False) -> bool:
        """Route ``pose`` to its player's buffer (see :meth:`PoseBuffer.push`)."""
        buf = self._buffers.get(pose.player)
        if buf is None:
            buf = self._buffers[pose.player] = PoseBuffer(self.config)
            while len(self._buffers) > self.max_players:
                self._buffers.popitem(last=False)
        self._buffers.move_to_end(pose.player)
        return buf.push(pose, keyframe=keyframe)

    def feed(self, event: object) -> None:
        """Take any client event: a pose is pushed (a v2 keyframe as a resync point), a
        ``leave`` forgets its player, a ``welcome`` (a join or a resume, maybe on another
        server clock) clears all."""
        if isinstance(event, Pose):
            self.push(event, keyframe=event.keyframe)
        elif isinstance(event, Presence) and event.event == "leave":
            self.forget(event.player)
        elif isinstance(event, Welcome):
            self.clear()

    def forget(self, player: str) -> None:
        self._buffers.pop(player, None)

    def clear(self) -> None:
        self._buffers.clear()

    def pose_at(self, player: str, time: float) -> InterpolatedPose | None:
        """``player``'s pose shown at server time ``time``, or ``None`` if unknown."""
        buf = self._buffers.get(player)
        return None if buf is None else buf.pose_at(time)

    def advance(self, time: float) -> dict[str, float]:
        """A display frame at ``time`` that draws none of the players: each buffer's
        :meth:`PoseBuffer.advance`; the server time each would show."""
        out = {}
        for player, buf in self._buffers.items():
            tau = buf.advance(time)
            if tau is not None:
                out[player] = tau
        return out

    def poses_at(self, time: float) -> dict[str, InterpolatedPose]:
        """Every known player's pose shown at server time ``time``: each buffer's
        :meth:`PoseBuffer.pose_at`, their samples made in one batch."""
        begun = []
        for player, buf in self._buffers.items():
            plan = buf._begin(time)
            if plan is not None:
                begun.append((player, buf, plan))
        samples = make_samples([plan for _, _, plan in begun])
        frames = [
            (buf, plan, pos, rot) for (_, buf, plan), (pos, rot) in zip(begun, samples, strict=True)
        ]
        shown = _finish_all(frames)
        return {player: pose for (player, _, _), pose in zip(begun, shown, strict=True)}
