"""The SSI engine: every player advances one frame per tick, all in one batch.

Per tick, for all ``P`` players x ``N`` samples at once:

1. tracker frames -> calibrated positions -> features ``(P, 24)`` (``(P, 36)`` for the
   headset-only layout, see :mod:`posecast.tracking.layouts`)
2. one decoder step on ``P*N`` rows -> rotations, contacts, next hidden states (and,
   for ``hmd3``, each sample's pelvis pose in the head's yaw frame)
3. one candidate-pool step: FK with the root from the waist tracker (``hmd3``: from
   the sample's own pelvis output), per-sample contact IK, and the anomaly error ``R``
   of every sample
4. each player's selector decides whether its current sample must give way (detected
   at frame ``n``, the newest)
5. emit frame ``n - tau`` per player: the current sample's pose, or during a
   transition the decoder re-run on the interpolated latent and hidden state
   (one more batched call), on the pelvis averaged with frames ``n - tau - 1`` and
   ``n - tau + 1`` (:mod:`posecast.online.engine.pelvis`; a guessed pelvis then
   moved toward trackers beyond reach, ``upper_ik.reach_root``), then that player's own
   display IK, the floor pass (with the swing clearance,
   :mod:`posecast.online.engine.clearance`), a tracker set's leg pass, the knees
   onto their hinges (:mod:`posecast.online.engine.hinge`), then the upper-body pass
   (:mod:`posecast.online.engine.upper_ik`, run by the backend, ``Pool.upper_body``:
   head and hands on their trackers) and the
   elbows onto their hinges

The engine is pure: frames go in with :meth:`Engine.push`, :meth:`Engine.tick`
returns poses and events (:mod:`posecast.online.engine.types`). No sockets, no
clocks, no threads; steps 2 and 3 are a backend's :class:`~posecast.online.engine.ports.StepDecoder`
and :class:`~posecast.online.engine.ports.Pool`, which arrive built
(:func:`posecast.online.inference.loader.load_engine` loads the shipped models on the backend
named). One engine serves one model (one layout);
:class:`posecast.online.engine.multi.MultiEngine` batches each model's players together
when a server serves several. The ``sites`` model serves every tracker set
(:mod:`posecast.tracking.sites`) in one batch: a player's frame has one row per site
(absent ones ignored), its features carry which sites it tracks and how, and its
pelvis is its waist tracker's when the set has a positional waist, else the decoder's.

Look-ahead (paper Sec. 3.2.4): each player keeps a ring of ``tau + 1`` frames of
inputs, pre-step hidden states and raw outputs for all samples. An outlier found at
frame ``n`` starts a transition whose first interpolated frame is
``n - min(tau, T) + 1``, none of which has been emitted yet; with ``tau = T`` the
new sample is fully in place exactly at the frame where the outlier would have shown.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.fk import fk_positions
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.online.engine.apart import MAX_OVERLAP_M, keep_apart, overlap
from posecast.online.engine.batch_fk import fk32, pelvis_from_head32
from posecast.online.engine.calibration import (
    Calibration,
    WaistFilter,
    apply_all,
    orient_all,
    recalibrate,
)
from posecast.online.engine.clearance import TOES, clearance_lift, toe_speed
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.hinge import ELBOW_LIMBS, KNEE_LIMBS
from posecast.online.engine.ik import LEGS, floor_ik, floor_lift
from posecast.online.engine.leg_ik import senses_legs, solve_legs, tracks_legs
from posecast.online.engine.pelvis import smooth_pelvis
from posecast.online.engine.ports import Pool, PoolIK, StepDecoder
from posecast.online.engine.selectors import (
    AnomalySelector,
    DefaultSelector,
    SampleSelector,
    choose_anomaly_rows,
    off_the_floor,
)
from posecast.online.engine.slots import SlotArrays
from posecast.online.engine.types import (
    EngineEvent,
    EngineEventKind,
    PoseOut,
    TickResult,
    TrackerFrame,
)
from posecast.online.engine.upper_ik import (
    LEAN_JOINTS,
    SPAN_SHARE,
    ease_reach,
    lean_root,
    reach_root,
    turn_pelvis,
)
from posecast.skeleton import NUM_JOINTS, REST_PELVIS_HEIGHT_M, Joint, reference_offsets
from posecast.tracking.features import TRACKER_JOINT_INDEX, TrackerSlot
from posecast.tracking.layouts import Layout, spec
from posecast.tracking.sites import SITE_JOINT_INDEX, Kind, TrackerSet

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass
class _Transition:
    src: int
    dst: int
    start: int  # first frame with a weight above zero


@dataclass
class _Player:
    id: str
    slot: int
    selector: SampleSelector
    calibration: Calibration
    waist_filter: WaistFilter | None
    frames: int = 0  # frames stepped so far
    current: int = 0
    plan: _Transition | None = None
    pending: TrackerFrame | None = None
    last: TrackerFrame | None = None
    missing: int = 0
    stale: bool = False
    transitions: int = 0
    # The swing clearance's state: the shown toes' horizontal positions at the last
    # emitted frame (None before the first) and their averaged speed.
    toe_xz: F64 | None = None
    toe_speed: NDArray[np.floating] = field(default_factory=lambda: np.zeros(2))
    # The shown move of a guessed pelvis toward out-of-reach trackers at the last
    # emitted frame (upper_ik.ease_reach; None before the first).
    reach: F64 | None = None


class Engine:
    """Batched SSI for many players. See the module docstring for one tick's steps.

    Args:
        decoder, pool: a backend's two halves (``load_backend`` in
            :mod:`posecast.online.inference.auto`); the pool's contact-IK settings
            should be this ``cfg``'s.
        cfg: sample selection and interpolation settings (defaults: :class:`EngineConfig`).
        capacity: player slots preallocated (doubles when full).
        backend_name: which backend ``decoder`` and ``pool`` are, for logs and reports.
    """

    def __init__(
        self,
        decoder: StepDecoder,
        pool: Pool,
        cfg: EngineConfig | None = None,
        capacity: int = 8,
        *,
        backend_name: str = "custom",
    ) -> None:
        self.cfg = cfg or EngineConfig()
        self.decoder = decoder
        self.pool = pool
        self.backend_name = backend_name
        mc = decoder.meta["model_config"]
        self.latent, self.hidden = int(mc["latent"]), int(mc["hidden"])
        self.layout = spec(decoder.meta.get("layout", Layout.HMD3_WAIST))
        self._sites = self.layout.layout is Layout.SITES
        n_root = self.layout.root_outputs
        rows = self.layout.rows
        N = self.cfg.samples
        # Ring rows: tau + 1 frames of history, plus the row the decoder writes the next
        # hidden states into while frame n - tau is still being emitted.
        L = self._ring = self.cfg.lookahead + 2
        self._tick = 0
        self.slots = SlotArrays(
            {
                "eps": ((N, self.latent), np.float32),
                "zc": ((N, decoder.cache_width), np.float32),  # the decoder's latent cache
                "ik_locked": ((N, 2), np.bool_),
                "ik_lock_pos": ((N, 2, 3), np.float64),
                "ik_release": ((N, 2), np.int64),
                "ik_suppressed": ((N, 2), np.bool_),
                "disp_locked": ((2,), np.bool_),
                "disp_lock_pos": ((2, 3), np.float64),
                "disp_release": ((2,), np.int64),
                "disp_suppressed": ((2,), np.bool_),
                "ring_h": ((N, self.hidden), np.float32, L),  # hidden state before the frame
                "ring_rot": ((N, 108), np.float32, L),
                "ring_con": ((N, 2), np.float32, L),
                "ring_x": ((self.layout.n_features,), np.float32, L),
                "ring_root": ((N, max(1, n_root)), np.float32, L),  # hmd3: pelvis outputs
                "ring_pos": ((rows, 3), np.float64, L),  # calibrated tracker positions
                "ring_quat": ((rows, 4), np.float64, L),
                "kinds": ((rows,), np.int8),  # sites: each row's Kind (0 elsewhere)
                "ring_rootm": ((3, 3), np.float32, L),  # the waist's rotation (waist layouts)
                "ring_seq": ((), np.int64, L),
                "ring_held": ((), np.bool_, L),
            },
            capacity,
        )
        self.players: dict[str, _Player] = {}
        self._order: list[str] = []  # player id per slot
        self._world = np.empty((0, NUM_JOINTS, 3), np.float32)  # the pool's output, grown
        self._rest = rest_frame(rows)

    # --- membership -----------------------------------------------------------------

    def add_player(
        self,
        player: str,
        seed: int,
        selector: SampleSelector | None = None,
        calibration: Calibration | None = None,
        tracker_set: TrackerSet | None = None,
    ) -> None:
        """Join ``player``. Its ``N`` latent samples are drawn from ``seed``; sample 0 is
        the prior's mean (``eps = 0``) and starts as the current sample. A ``sites``
        engine needs the player's ``tracker_set`` (its frames' rows are model rows,
        :meth:`TrackerSet.to_rows`)."""
        if player in self.players:
            raise ValueError(f"player {player!r} is already in the engine")
        if (tracker_set is not None) != self._sites:
            raise ValueError(
                "a sites engine needs each player's tracker set"
                if self._sites
                else f"a {self.layout.layout} engine takes no tracker set"
            )
        slot = self.slots.add()
        self.slots["kinds"][slot] = 0 if tracker_set is None else tracker_set.kinds()
        eps = np.random.default_rng(seed).standard_normal((self.cfg.samples, self.latent))
        eps *= self.cfg.latent_scale
        eps[0] = 0.0
        self._set_eps(slot, slice(None), eps)
        wf = (
            WaistFilter(self.cfg.waist_filter_hz, self.cfg.fps)
            if self.cfg.waist_filter_hz and not self.layout.predicts_root
            else None
        )
        self.players[player] = _Player(
            player,
            slot,
            self._resolve(selector or DefaultSelector()),
            calibration or Calibration(),
            wf,
        )
        self._order.append(player)

    def remove_player(self, player: str) -> None:
        p = self.players.pop(player)
        moved = self.slots.remove(p.slot)
        last_id = self._order.pop()
        if moved is not None:
            self._order[p.slot] = last_id
            self.players[last_id].slot = p.slot

    def set_latents(self, player: str, eps: NDArray[np.floating], samples: Any = None) -> None:
        """Replace the latents ``eps (n, latent)`` of ``player``'s samples ``samples``
        (an index, slice or index array; ``None``: all ``N``), cache included."""
        self._set_eps(self.players[player].slot, slice(None) if samples is None else samples, eps)

    def _set_eps(self, slot: int, samples: Any, eps: NDArray[np.floating]) -> None:
        self.slots["eps"][slot, samples] = eps
        rows = np.asarray(self.slots["eps"][slot, samples], np.float32).reshape(-1, self.latent)
        shape = self.slots["zc"][slot, samples].shape
        self.slots["zc"][slot, samples] = self.decoder.cache_latents(rows).reshape(shape)

    def set_selector(self, player: str, selector: SampleSelector) -> None:
        """``player`` selects with ``selector`` from the next tick (a
        :class:`~.selectors.DefaultSelector`: the engine's configured anomaly selector)."""
        self.players[player].selector = self._resolve(selector)

    def _resolve(self, selector: SampleSelector) -> SampleSelector:
        if not isinstance(selector, DefaultSelector):
            return selector
        factor = self.cfg.outlier_factor if selector.factor is None else selector.factor
        home = self.cfg.home_factor
        return AnomalySelector(
            factor, self.cfg.outlier_baseline, None if home is None else min(home, factor)
        )

    def set_calibration(self, player: str, calibration: Calibration) -> None:
        """Calibrate ``player`` anew from its next frame on. The frames already in its
        look-ahead, and every tracker-space state of its shown pose (contact locks,
        the clearance's toes, the reach move), are re-expressed in the new calibration,
        so the poses still to come are divided by the scale their positions carry and
        the next frame's velocities are measured from the same calibration."""
        p = self.players[player]
        old, p.calibration = p.calibration, calibration
        if old == calibration:
            return
        s, k = self.slots, p.slot
        ratio = calibration.scale / old.scale
        pos, q = recalibrate(old, calibration, s["ring_pos"][:, k], s["ring_quat"][:, k])
        if not self.layout.predicts_root:  # the pelvis is the waist tracker's
            s["ring_rootm"][:, k] = quat2mat(q[:, TrackerSlot.WAIST])
        s["ring_pos"][:, k], s["ring_quat"][:, k] = pos, q
        for name in ("ik_lock_pos", "disp_lock_pos"):
            s[name][k] *= ratio
        if p.toe_xz is not None:
            p.toe_xz = p.toe_xz * ratio
        if p.reach is not None:
            p.reach = p.reach * ratio

    def push(self, player: str, frame: TrackerFrame) -> None:
        """Offer the newest frame; a newer push before the tick replaces it."""
        self.players[player].pending = frame

    def current_sample(self, player: str) -> int:
        return self.players[player].current

    def transitions(self, player: str) -> int:
        return self.players[player].transitions

    @property
    def player_count(self) -> int:
        return self.slots.count

    # --- the tick ---------------------------------------------------------------------

    def tick(self) -> TickResult:
        P, N = self.slots.count, self.cfg.samples
        if P == 0:
            self._tick += 1
            return TickResult([], [], 0)
        s, L = self.slots, self._ring
        k = self._tick % L
        events = self._gather_inputs(k)
        pos, quat = s.row("ring_pos", k), s.row("ring_quat", k)  # (P, 4, 3), (P, 4, 4)
        R = P * N
        # One decoder step for all P*N samples: it reads the hidden states from this
        # frame's ring row and writes the next ones straight into the following row.
        outputs = {
            "rotations": s.row("ring_rot", k).reshape(R, 108),
            "contacts": s.row("ring_con", k).reshape(R, 2),
            "h_out": s.row("ring_h", (k + 1) % L).reshape(R, self.hidden),
        }
        if self.layout.predicts_root:
            outputs["root"] = s.row("ring_root", k).reshape(R, self.layout.root_outputs)
        self.decoder.step(
            s.row("ring_x", k),  # (P, F): a player's row serves its N samples
            N,
            s.view("zc").reshape(R, -1),
            s.row("ring_h", k).reshape(R, self.hidden),
            outputs,
        )
        # One pool step: FK, contact IK and anomaly error of every sample.
        root_mat, root_pos, group = self._roots(
            pos, quat, s.row("ring_rootm", k), outputs.get("root"), N, self._waist_rows()
        )
        if len(self._world) < R:
            self._world = np.empty((R, NUM_JOINTS, 3), np.float32)
        world = self._world[:R]
        ik = PoolIK(*(s.view(f"ik_{n}").reshape(R, *_IK_SHAPES[n]) for n in _IK_SHAPES))
        scores = self.pool.step(
            outputs["rotations"], outputs["contacts"], root_mat, root_pos, group, ik, world
        ).reshape(P, N)
        wp = world.reshape(P, N, NUM_JOINTS, 3)

        started = self._select(self._floor_check(np.asarray(scores, np.float64), wp), wp)
        poses = self._emit()
        for pid in self._order:
            self.players[pid].frames += 1
        self._tick += 1
        return TickResult(poses, events, started)

    def _waist_rows(self, slots: Any = None) -> NDArray[np.bool_] | None:
        """Sites: per player slot (all, or ``slots``), whether its pelvis is its waist
        tracker's; ``None`` for the other layouts."""
        if not self._sites:
            return None
        kinds = self.slots.view("kinds")[:, TrackerSlot.WAIST]
        tracked: NDArray[np.bool_] = kinds == Kind.POSITIONAL
        return tracked if slots is None else tracked[slots]

    def _roots(
        self,
        pos: F64,
        quat: F64,
        rootm: F32,
        root_out: F32 | None,
        repeat: int,
        waist: NDArray[np.bool_] | None = None,
    ) -> tuple[F32, F32, int]:
        """World pelvis rotations ``(G, 3, 3)`` and positions ``(G, 3)`` (float32) for
        ``R = len(pos) * repeat`` decoded rows, and how many rows share each: ``R / G``.

        ``hmd3+waist``: the waist tracker's (``rootm``, its rotation as the ring keeps
        it), one per player (``G = len(pos)``), shared by its ``repeat`` rows.
        ``hmd3``: each row's own pelvis output (6D rotation, position), moved out of
        the player's head frame into the world (``G = R``).
        ``sites``: as ``hmd3``, except that the rows of a player whose set tracks the
        waist's position (``waist``, per player) take the waist tracker's pose.
        """
        if root_out is None:
            return rootm, pos[:, TrackerSlot.WAIST].astype(np.float32), repeat
        mats, places = pelvis_from_head32(
            root_out, pos[:, TrackerSlot.HEAD], quat[:, TrackerSlot.HEAD]
        )
        if waist is not None and waist.any():
            rows = np.repeat(waist, repeat)
            players = np.flatnonzero(waist)
            wm = quat2mat(quat[players, TrackerSlot.WAIST]).astype(np.float32)
            mats[rows] = np.repeat(wm, repeat, axis=0)
            places[rows] = np.repeat(
                pos[players, TrackerSlot.WAIST].astype(np.float32), repeat, axis=0
            )
        return mats, places, 1

    def newest_inputs(
        self, player: str
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
        """What the last tick fed the decoder for ``player``'s newest frame (copies):
        its features ``(F,)``, calibrated tracker positions ``(rows, 3)`` and
        orientations ``(rows, 4)``."""
        k, slot = (self._tick - 1) % self._ring, self.players[player].slot
        s = self.slots
        return (
            s["ring_x"][k, slot].copy(),
            s["ring_pos"][k, slot].copy(),
            s["ring_quat"][k, slot].copy(),
        )

    def hidden_state(self, player: str) -> NDArray[np.float32]:
        """The GRU states ``(N, 128)`` the next tick decodes from (a writable view)."""
        out: NDArray[np.float32] = self.slots["ring_h"][
            self._tick % self._ring, self.players[player].slot
        ]
        return out

    def _gather_inputs(self, k: int) -> list[EngineEvent]:
        """Write this frame's inputs into ring row ``k``; hold missing frames.

        Per player only the bookkeeping (missing, stale, which frame); calibration,
        the hold and the features run once over all players.
        """
        kp = (k - 1) % self._ring
        events: list[EngineEvent] = []
        s = self.slots
        fresh: list[tuple[_Player, TrackerFrame]] = []
        held: list[int] = []  # slots without a new frame (a rest frame stands in too)
        kept: list[int] = []  # slots whose inputs stay those of the frame before
        gaps: dict[int, int] = {}  # per fresh row: the frames held since its last one
        for pid in self._order:
            p = self.players[pid]
            frame = p.pending
            p.pending = None
            if frame is None:
                held.append(p.slot)
                p.missing += 1
                if p.missing >= self.cfg.stale_after_frames and not p.stale:
                    p.stale = True
                    events.append(EngineEvent(EngineEventKind.STALE, pid))
                if p.last is None:
                    # Nothing ever arrived: stand still at the origin in the rest pose.
                    fresh.append((p, self._rest))
                else:
                    kept.append(p.slot)
                continue
            if p.missing and p.last is not None:
                gaps[len(fresh)] = p.missing
            p.missing = 0
            if p.stale:
                p.stale = False
                events.append(EngineEvent(EngineEventKind.ACTIVE, pid))
            fresh.append((p, frame))
        s["ring_held"][k, : s.count] = False
        s["ring_held"][k, held] = True
        if kept:
            for name in ("ring_x", "ring_pos", "ring_quat", "ring_rootm", "ring_seq"):
                s[name][k, kept] = s[name][kp, kept]
        if not fresh:
            return events
        players = [p for p, _ in fresh]
        idx = [p.slot for p in players]
        q = np.array([f.quat for _, f in fresh], dtype=np.float64)  # (M, rows, 4)
        for i, (p, f) in enumerate(fresh):
            if p.waist_filter is not None and f is not self._rest:  # not the stand-in
                q[i, TrackerSlot.WAIST] = p.waist_filter(q[i, TrackerSlot.WAIST])
        calibrations = [p.calibration for p in players]
        q = orient_all(calibrations, q)
        raw = np.array([f.pos for _, f in fresh], dtype=np.float64)  # (M, rows, 3)
        if self._sites:  # the rest frame's inertial rows read no acceleration
            rest = [i for i, (_, f) in enumerate(fresh) if f is self._rest]
            if rest:
                still = s["kinds"][[players[i].slot for i in rest]] == Kind.INERTIAL
                raw[rest] = np.where(still[..., None], 0.0, raw[rest])
        if self.layout.layout is Layout.HMD3:
            # No waist: keep the unused slot finite whatever the client sent.
            raw[:, TrackerSlot.WAIST], q[:, TrackerSlot.WAIST] = raw[:, TrackerSlot.HEAD], _IDENT
        cal = apply_all(calibrations, raw, q)
        # Velocities from the frame before; a player's first frame has none, and one
        # after missing frames moved over all of them (the ring held the last one).
        first = [i for i, p in enumerate(players) if p.last is None]
        prev = s["ring_pos"][kp, idx]
        prev[first] = cal[first]
        for i, gap in gaps.items():
            prev[i] = cal[i] - (cal[i] - prev[i]) / (gap + 1)
        s["ring_pos"][k, idx] = cal
        s["ring_quat"][k, idx] = q
        if not self.layout.predicts_root:  # the pelvis is the waist tracker's, per frame
            s["ring_rootm"][k, idx] = quat2mat(q[:, TrackerSlot.WAIST])
        s["ring_seq"][k, idx] = [f.seq for _, f in fresh]
        kinds = s["kinds"][idx] if self._sites else None
        s["ring_x"][k, idx] = self.layout.features(cal, prev, q, self.cfg.fps, kinds)
        for p, f in fresh:
            if f.seq >= 0:
                p.last = f
        return events

    def _floor_check(self, scores: F64, positions: F32) -> F64:
        """``scores (P, N)`` with ``+inf`` for every sample out of its player's pool this
        frame (``EngineConfig.floor_select``; :func:`.selectors.off_the_floor`).
        The anomaly error judges a pose in the character frame and cannot see the
        floor; without the check SSI moved crouching players onto straight-legged
        samples whose feet then showed half a metre under it (docs/evaluation.md)."""
        if not (self.cfg.floor_select and self.cfg.floor_ik):
            return scores
        return np.asarray(off_the_floor(scores, positions), np.float64)

    def _select(self, scores: F64, positions: F32) -> int:
        """Run every idle player's selector at the newest frame (``scores (P, N)``,
        ``positions (P, N, 19, 3)``); plan the transitions asked for, return how many.

        A player in a transition is not asked. Players on an :class:`AnomalySelector`
        (the default) are decided together on the score matrix, exactly as each
        selector would decide alone; any other selector is asked player by player.
        """
        moves: list[tuple[_Player, int]] = []
        rows: list[int] = []
        batch: list[tuple[_Player, AnomalySelector]] = []
        for i, pid in enumerate(self._order):
            p = self.players[pid]
            if p.plan is not None:
                continue
            sel = p.selector
            if type(sel) is AnomalySelector:  # not a subclass: it could choose otherwise
                rows.append(i)
                batch.append((p, sel))
                continue
            best = sel.choose(p.current, scores[i], positions[i])
            if best is not None and best != p.current:
                moves.append((p, best))
        if batch:
            chosen = choose_anomaly_rows(
                np.array([p.current for p, _ in batch], np.intp),
                scores[rows],
                np.array([sel.factor for _, sel in batch], np.float64),
                np.array([sel.baseline == "min" for _, sel in batch]),
                None
                if all(sel.home is None for _, sel in batch)
                else np.array([np.nan if sel.home is None else sel.home for _, sel in batch]),
            )
            moves += [(p, b) for (p, _), b in zip(batch, chosen.tolist(), strict=True) if b >= 0]
        start_in = min(self.cfg.lookahead, self.cfg.transition_frames) - 1
        for p, best in moves:
            p.plan = _Transition(p.current, best, p.frames - start_in)
            p.current = best
            p.transitions += 1
        return len(moves)

    def _emit(self) -> list[PoseOut]:
        tau, T = self.cfg.lookahead, self.cfg.transition_frames
        s = self.slots
        k = (self._tick - tau) % self._ring  # ring row of frame n - tau, for every player
        emit: list[tuple[_Player, int, float]] = []  # player, sample, weight
        # Frame e is the player's first, or its first real one after rest frames (a
        # player added before its first frame stands at the origin): no frame e - 1.
        firsts: list[bool] = []
        before = s["ring_seq"][(k - 1) % self._ring]
        for pid in self._order:
            p = self.players[pid]
            e = p.frames - tau
            if e < 0:
                continue
            firsts.append(e == 0 or bool(before[p.slot] < 0 <= s["ring_seq"][k, p.slot]))
            if p.plan is None or e < p.plan.start:
                emit.append((p, p.plan.src if p.plan is not None else p.current, 0.0))
            else:
                emit.append((p, p.plan.dst, min(1.0, (e - p.plan.start + 1) / T)))
        if not emit:
            return []
        slots = np.array([p.slot for p, _, _ in emit])
        samples = np.array([sample for _, sample, _ in emit])
        rot = s["ring_rot"][k, slots, samples]  # (E, 108) copies
        con = s["ring_con"][k, slots, samples]
        root = s["ring_root"][k, slots, samples] if self.layout.predicts_root else None
        interp = [i for i, (_, _, w) in enumerate(emit) if 0.0 < w < 1.0]
        # The emitted samples' own pelvis outputs, before a transition's blend replaces
        # them (None: no blend): the pelvis smoothing takes its neighbours' motion from these.
        root_own = root.copy() if root is not None and interp else None
        if interp:
            # Re-decode on the blended latent and hidden state. The cache is affine in
            # the latent, so the blend of two caches is the cache of the blended latent.
            plans = [emit[i][0].plan for i in interp]
            src = np.array([t.src for t in plans if t is not None])
            dst = np.array([t.dst for t in plans if t is not None])
            weight = np.array([emit[i][2] for i in interp])
            # Weights in float32, as a Python float scales a float32 row: (E, 1)
            w_src = (1 - weight).astype(np.float32)[:, None]
            w_dst = weight.astype(np.float32)[:, None]
            at = slots[interp]
            zs = w_src * s["zc"][at, src] + w_dst * s["zc"][at, dst]  # (E, W)
            hs = w_src * s["ring_h"][k, at, src] + w_dst * s["ring_h"][k, at, dst]  # (E, H)
            E = len(interp)
            out = {
                "rotations": np.empty((E, 108), np.float32),
                "contacts": np.empty((E, 2), np.float32),
                "h_out": np.empty((E, self.hidden), np.float32),  # not kept
            }
            if root is not None:
                out["root"] = np.empty((E, self.layout.root_outputs), np.float32)
            self.decoder.step(s["ring_x"][k, at], 1, zs, hs, out)
            rot[interp], con[interp] = out["rotations"], out["contacts"]
            if root is not None:
                root[interp] = out["root"]
        for p, _, w in emit:
            if p.plan is not None and w >= 1.0:
                p.plan = None
        pos, quat = s["ring_pos"][k, slots], s["ring_quat"][k, slots]
        waist = self._waist_rows(slots)
        root_mat, root_pos, _ = self._roots(pos, quat, s["ring_rootm"][k, slots], root, 1, waist)
        if self.cfg.pelvis_smoothing and tau >= 1:
            root_mat, root_pos = self._smooth_roots(
                k, slots, samples, np.array(firsts), root_own, root_mat, root_pos, waist
            )
        free = None  # per emitted pose, whether its pelvis is the decoder's guess
        if self.layout.predicts_root:
            free = np.ones(len(emit), np.bool_) if waist is None else ~waist
        if (self.cfg.reaches or self.cfg.leans) and free is not None and free.any():
            # A guessed pelvis leans so that the line to the head meets the headset
            # (upper_ik.lean_root), then moves toward the trackers it cannot reach
            # (upper_ik.reach_root), before the display IK plants the feet.
            rows = np.flatnonzero(free)
            _, near32 = fk32(rot[rows], root_mat[rows], root_pos[rows], False, LEAN_JOINTS)
            near: NDArray[np.floating] = near32
            # A set that senses its legs keeps its hips as they are and its height.
            sensed = senses_legs(s["kinds"][slots[rows]]) if self._sites else None
            if self.cfg.leans:
                head = near[:, Joint.HEAD]
                turn = lean_root(root_pos[rows], head, pos[rows, TrackerSlot.HEAD])
                if sensed is not None:
                    turn[sensed] = np.eye(3)
                root_mat = root_mat.copy()
                rot[rows], root_mat[rows] = turn_pelvis(rot[rows], root_mat[rows], turn)
                pivot = root_pos[rows, None].astype(np.float64)
                lean = list(LEAN_JOINTS)
                # Only LEAN_JOINTS' rows of fk32's output are defined: the others are
                # whatever the buffer held, which a cast to float64 may trip on
                # (a signalling NaN raises "invalid value"), so they are not cast.
                leant = np.zeros(near.shape, np.float64)
                leant[:, lean] = pivot + np.einsum("eab,ekb->eka", turn, near[:, lean] - pivot)
                near = leant
            if self.cfg.reaches:
                span = None if sensed is None else np.where(sensed, 0.0, SPAN_SHARE)
                target = reach_root(near, pos[rows], span if self.cfg.torso_span else 0.0)
                root_pos = root_pos.copy()
                for r, i in enumerate(rows.tolist()):
                    p = emit[i][0]
                    p.reach = ease_reach(None if firsts[i] else p.reach, target[r])
                    root_pos[i] += p.reach.astype(np.float32)
        # FK and the players' own display IK, batched: gather their states, step,
        # scatter back.
        E = len(emit)
        state = {n: s[n][slots] for n in _DISPLAY_IK}
        ik = PoolIK(
            *(
                state[n].reshape(E, *shape)
                for n, shape in zip(_DISPLAY_IK, _IK_SHAPES.values(), strict=True)
            )
        )
        wp, rotations = self.pool.emit(rot, con, root_mat, root_pos, ik)
        for n in _DISPLAY_IK:
            s[n][slots] = state[n]
        if self.cfg.legs_apart:
            _apart(wp, rotations, rot, root_mat, root_pos)
        if self.cfg.floor_ik:
            lift = floor_lift(wp)
            if self.cfg.swing_clearance:
                speed = self._toe_speeds(emit, wp, firsts)
                lift = np.maximum(lift, clearance_lift(wp, speed))
            _floor(wp, rotations, lift)
        reach_limited = np.zeros(E, np.bool_)
        if self.cfg.upper_body_ik and self._sites:
            # A tracker set's positional feet and knees: the legs onto their trackers.
            kinds = s["kinds"][slots]
            legs = np.flatnonzero(tracks_legs(kinds))
            if len(legs):
                wp[legs], rotations[legs], reach_limited[legs] = solve_legs(
                    wp[legs], rotations[legs], pos[legs], quat[legs], kinds[legs]
                )
        if self.cfg.knee_hinge:
            self.pool.hinge(wp, rotations, KNEE_LIMBS)
        if self.cfg.upper_body_ik:
            # Head and hands onto their (calibrated) trackers, before the user's scale
            # (a pelvis from the decoder may follow the head).
            wp, rotations, upper_limited = self.pool.upper_body(
                wp, rotations, pos, quat, free, self.cfg.wrist_elbow
            )
            reach_limited |= upper_limited
        if self.cfg.elbow_hinge:
            self.pool.hinge(wp, rotations, ELBOW_LIMBS)
        limited = reach_limited.tolist()
        scale = np.array([p.calibration.scale for p, _, _ in emit], np.float32)
        positions = wp / scale[:, None, None]
        seqs, held = s["ring_seq"][k, slots].tolist(), s["ring_held"][k, slots].tolist()
        scales = scale.astype(np.float64).tolist()
        return [
            PoseOut(
                player=p.id,
                seq=seqs[i],
                positions=positions[i],
                rotations=rotations[i],
                contacts=con[i],
                sample=sample,
                transitioning=0.0 < w < 1.0,
                held=held[i],
                reach_limited=limited[i],
                scale=scales[i],
            )
            for i, (p, sample, w) in enumerate(emit)
        ]

    def _toe_speeds(
        self, emit: list[tuple[_Player, int, float]], wp: F32, firsts: list[bool]
    ) -> NDArray[np.floating]:
        """The emitted players' averaged toe speeds ``(E, 2)``
        (:func:`~posecast.online.engine.clearance.toe_speed`) from their shown poses
        ``wp`` before any lift; each player's state moves on to this frame. A player's
        first (real) frame starts at rest."""
        xz = wp[:, TOES][:, :, [0, 2]].astype(np.float64)
        prev, was = xz.copy(), np.zeros((len(emit), 2))  # at rest, where a player starts
        for i, ((p, _, _), first) in enumerate(zip(emit, firsts, strict=True)):
            if p.toe_xz is not None and not first:
                prev[i], was[i] = p.toe_xz, p.toe_speed
        speed = toe_speed(prev, xz, was, self.cfg.fps)
        for i, (p, _, _) in enumerate(emit):
            p.toe_xz, p.toe_speed = xz[i], speed[i]
        return speed

    def _smooth_roots(
        self,
        k: int,
        slots: NDArray[np.intp],
        samples: NDArray[np.intp],
        first: NDArray[np.bool_],
        root_own: F32 | None,
        root_mat: F32,
        root_pos: F32,
        waist: NDArray[np.bool_] | None,
    ) -> tuple[F32, F32]:
        """The shown pelvis at ring row ``k`` (frame ``e``) averaged with frames ``e - 1``
        and ``e + 1`` (:func:`~posecast.online.engine.pelvis.smooth_pelvis`; the look-ahead
        holds ``e + 1``, the ring still holds ``e - 1``). A neighbour is the emitted
        sample's own pelvis there, moved by the difference between the shown pelvis and
        that sample's at ``e`` (they differ during a transition's blend); a player's first
        frame stands in for its missing ``e - 1``."""
        s, L = self.slots, self._ring
        own = (root_mat, root_pos)
        if root_own is not None:
            m, p, _ = self._roots(
                s["ring_pos"][k, slots],
                s["ring_quat"][k, slots],
                s["ring_rootm"][k, slots],
                root_own,
                1,
                waist,
            )
            own = (m, p)
        # Both neighbours in one call: frame e - 1 (or e, on a first frame), then e + 1
        # (or e, on the last rest frame before a player's first real one).
        E = len(slots)
        nxt = (k + 1) % L
        last_rest = (s["ring_seq"][k, slots] < 0) & (s["ring_seq"][nxt, slots] >= 0)
        rows = np.concatenate([np.where(first, k, (k - 1) % L), np.where(last_rest, k, nxt)])
        at = np.concatenate([slots, slots])
        m, p, _ = self._roots(
            s["ring_pos"][rows, at],
            s["ring_quat"][rows, at],
            s["ring_rootm"][rows, at],
            s["ring_root"][rows, at, np.concatenate([samples, samples])]
            if self.layout.predicts_root
            else None,
            1,
            None if waist is None else np.concatenate([waist, waist]),
        )
        mats: NDArray[np.floating] = m.reshape(2, E, 3, 3)
        places: NDArray[np.floating] = p.reshape(2, E, 3)
        if root_own is not None:  # a blend: move the sample's own motion onto it
            mats = (mats @ np.swapaxes(own[0], -1, -2)) @ root_mat
            places = root_pos + (places - own[1])
        mat, pos = smooth_pelvis((mats[0], root_mat, mats[1]), (places[0], root_pos, places[1]))
        return mat.astype(np.float32), pos.astype(np.float32)


def _floor(wp: F32, rotations: F32, lift: NDArray[np.floating]) -> None:
    """:func:`~posecast.online.engine.ik.floor_ik` on shown poses, in place: positions
    ``(E, 19, 3)`` and world rotations ``(E, 19, 4)`` (the thighs' and shins' change),
    each foot lifted by ``lift (E, 2)``."""
    rows = np.flatnonzero(lift.any(axis=1))
    if not len(rows):
        return
    pos = wp[rows].astype(np.float64)
    mat = quat2mat(rotations[rows].astype(np.float64))
    floor_ik(mat, pos, lift=lift[rows])
    wp[rows] = pos
    rotations[np.ix_(rows, _THIGHS_SHINS)] = mat2quat(mat[:, _THIGHS_SHINS])


def _apart(wp: F32, rotations: F32, rot: F32, root_mat: F32, root_pos: F32) -> None:
    """:func:`~posecast.online.engine.apart.keep_apart` on shown poses after the display
    contact IK, in place: positions ``(E, 19, 3)`` and world rotations ``(E, 19, 4)``
    (the thighs' and shins' change); the network's own legs come from the decoder's
    ``rot`` on the same pelvis, for the poses whose legs meet."""
    deep = overlap(wp)
    rows = np.flatnonzero(deep > MAX_OVERLAP_M)
    if not len(rows):
        return
    mat32, pos32 = fk32(rot[rows], root_mat[rows], root_pos[rows], True, _LEG_JOINTS)
    assert mat32 is not None
    # Only the legs' rows of fk32's output are defined (and all keep_apart reads).
    legs = list(_LEG_JOINTS)
    net_mat, net_pos = np.zeros((len(rows), NUM_JOINTS, 3, 3)), np.zeros((len(rows), NUM_JOINTS, 3))
    net_mat[:, legs], net_pos[:, legs] = mat32[:, legs], pos32[:, legs]
    pos = wp[rows].astype(np.float64)
    mat = quat2mat(rotations[rows].astype(np.float64))
    keep_apart(mat, pos, net_mat, net_pos, deep=deep[rows])
    wp[rows] = pos
    rotations[np.ix_(rows, _THIGHS_SHINS)] = mat2quat(mat[:, _THIGHS_SHINS])


_LEG_JOINTS = tuple(int(j) for leg in LEGS for j in leg)
_THIGHS_SHINS = np.array([int(j) for leg in LEGS for j in leg[:2]])  # what floor_ik turns


_DISPLAY_IK = ("disp_locked", "disp_lock_pos", "disp_release", "disp_suppressed")
# Per-sample shapes of the candidate pool's contact-IK state, in PoolIK's field order.
_IK_SHAPES: dict[str, tuple[int, ...]] = {
    "locked": (2,),
    "lock_pos": (2, 3),
    "release": (2,),
    "suppressed": (2,),
}


def rest_frame(rows: int) -> TrackerFrame:
    """What a player that never sent a frame stands on (seq -1: never kept as its
    last): the reference body in its rest pose at the origin, tracked on ``rows`` rows
    (4 tracker slots, or every site; ``_gather_inputs`` zeroes an inertial site's row,
    so it reads no acceleration)."""
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    pos = fk_positions(eye, np.array([0.0, REST_PELVIS_HEIGHT_M, 0.0]), reference_offsets())
    joints = TRACKER_JOINT_INDEX if rows == len(TRACKER_JOINT_INDEX) else SITE_JOINT_INDEX
    q = np.zeros((rows, 4))
    q[:, 3] = 1.0
    return TrackerFrame(-1, pos[list(joints)], q)


_IDENT = np.array([0.0, 0.0, 0.0, 1.0])
