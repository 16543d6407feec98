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
5. emit frame ``e = n - d`` per player (``d``: :attr:`EngineConfig.delay`; 0, the
   newest frame, unless ``delayed_emission``): the current sample's pose, or during a
   transition the decoder re-run on the interpolated latent and hidden state (one
   more batched call), through the shown pose's passes
   (:func:`posecast.body.pipeline.show`, docs/engine.md; FK with the display IK, the
   upper-body pass and the hinges run in the backend's pool), then a forecasting
   player's forecast (:mod:`.forecasting`)

The engine is pure: frames go in with :meth:`Engine.push`, :meth:`Engine.tick`
returns poses and events (:mod:`posecast.online.engine.types`); no sockets, clocks or
threads. Steps 2 and 3 are a backend's :class:`~.ports.StepDecoder` and
:class:`~.ports.Pool`, which arrive built (:func:`posecast.online.inference.loader.
load_engine`). One engine serves one model (one layout); :class:`.multi.MultiEngine`
batches each model's players when a server serves several. The ``sites`` model serves
every tracker set (:mod:`posecast.tracking.sites`) in one batch: a player's frame has
one row per site, its features carry which sites it tracks and how, and its pelvis is
its waist tracker's when the set has a positional waist, else the decoder's.

Look-ahead (paper Sec. 3.2.4): each player keeps a ring of ``tau + 1`` frames of
inputs, pre-step hidden states and raw outputs for all samples. An outlier found at
frame ``n`` starts a transition whose first interpolated frame is
``n - min(tau, T) + 1``: with ``delayed_emission`` and ``tau = T`` (the paper) the new
sample is in place where the outlier would have shown, every pose ``tau`` frames late;
without it frame ``n`` shows at once, ``min(tau, T) / T`` into the blend (docs/latency.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.body.forecast import MAX_FORECAST_MS
from posecast.body.pelvis import pelvis_poses
from posecast.body.pipeline import Decoded, ShownState, show
from posecast.geometry.rotations import quat2mat
from posecast.online.engine.calibration import Calibration, WaistFilter, recalibrate
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.forecasting import step_forecast
from posecast.online.engine.ports import Pool, PoolIK, StepDecoder
from posecast.online.engine.ring import Fed, pelvis_neighbours, rest_frame, write_inputs
from posecast.online.engine.selectors import (
    AnomalySelector,
    DefaultSelector,
    SampleSelector,
    choose_anomaly_rows,
    off_the_floor,
)
from posecast.online.engine.slots import SlotArrays
from posecast.online.engine.state import IK_SHAPES, RESCALED, SHOWN, state_specs
from posecast.online.engine.types import (
    EngineEvent,
    EngineEventKind,
    PoseOut,
    TickResult,
    TrackerFrame,
)
from posecast.skeleton import NUM_JOINTS
from posecast.tracking.features import TrackerSlot
from posecast.tracking.layouts import Layout, spec
from posecast.tracking.sites import Kind, TrackerSet

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
    forecast_ms: float = 0.0  # poses predicted this far ahead (body.forecast)
    shown: int = 0  # frames of shown history kept for the forecast (at most HISTORY)


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
        N = self.cfg.samples
        # Ring rows: tau + 1 frames of history, plus the row the decoder writes the next
        # hidden states into while frame n - d (d <= tau) is still being emitted.
        L = self._ring = self.cfg.lookahead + 2
        self._tick = 0
        self.slots = SlotArrays(
            state_specs(N, self.latent, decoder.cache_width, self.hidden, self.layout, L),
            capacity,
        )
        self.players: dict[str, _Player] = {}
        self._order: list[str] = []  # player id per slot
        self._world = np.empty((0, NUM_JOINTS, 3), np.float32)  # the pool's output, grown
        self._rest = rest_frame(self.layout.rows)

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
        the clearance's toes, the reach move, the planted toes), are re-expressed in
        the new calibration, so the poses still to come are divided by the scale their
        positions carry and the next frame's velocities are measured from the same
        calibration."""
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
        for name in RESCALED:
            s[name][k] *= ratio
        p.shown = 0  # the forecast's velocities start again in the new calibration

    def set_forecast(self, player: str, ms: float) -> None:
        """Stream ``player``'s poses predicted ``ms`` (0 to 100; 0: none) ahead of their
        frame, from its last ``HISTORY`` shown poses since this call or its last
        recalibration (:mod:`.forecasting`; a pose's ``ahead_ms`` says how far)."""
        if not 0.0 <= ms <= MAX_FORECAST_MS:  # NaN fails too
            raise ValueError(f"forecast_ms must be in [0, {MAX_FORECAST_MS:g}]")
        p = self.players[player]
        if ms != p.forecast_ms:
            p.forecast_ms, p.shown = float(ms), 0

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
        pelvis = pelvis_poses(
            pos, quat, s.row("ring_rootm", k), outputs.get("root"), N, self._waist_rows()
        )
        if len(self._world) < R:
            self._world = np.empty((R, NUM_JOINTS, 3), np.float32)
        world = self._world[:R]
        ik = PoolIK(*(s.view(f"ik_{n}").reshape(R, *IK_SHAPES[n]) for n in IK_SHAPES))
        scores = self.pool.step(
            outputs["rotations"], outputs["contacts"], pelvis, ik, world
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
        fresh: list[tuple[Fed, TrackerFrame]] = []
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
        write_inputs(s, k, kp, fresh, kept, held, gaps, self.layout, self.cfg.fps, self._rest)
        return events

    def _floor_check(self, scores: F64, positions: F32) -> F64:
        """``scores (P, N)`` with ``+inf`` for every sample out of its player's pool this
        frame (``EngineConfig.floor_select``; :func:`.selectors.off_the_floor`: the
        anomaly error cannot see the floor, docs/evaluation.md)."""
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
        d, T = self.cfg.delay, self.cfg.transition_frames
        s = self.slots
        k = (self._tick - d) % self._ring  # ring row of frame n - d, for every player
        emit: list[tuple[_Player, int, float]] = []  # player, sample, weight
        # Frame e is the player's first, or its first real one after rest frames (a
        # player added before its first frame stands at the origin): no frame e - 1.
        firsts: list[bool] = []
        before = s["ring_seq"][(k - 1) % self._ring]
        for pid in self._order:
            p = self.players[pid]
            e = p.frames - d
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
        root_mat, root_pos, _ = pelvis_poses(pos, quat, s["ring_rootm"][k, slots], root, 1, waist)
        neighbours = None
        if self.cfg.pelvis_smoothing:
            own = None  # the emitted samples' own pelvises, where a blend replaced them
            if root_own is not None:
                own = pelvis_poses(pos, quat, s["ring_rootm"][k, slots], root_own, 1, waist)[:2]
            neighbours = pelvis_neighbours(
                s, k, self._ring, self.layout, slots, samples, np.array(firsts), own,
                (root_mat, root_pos), waist, ahead=d >= 1,
            )  # fmt: skip
        free = None  # per emitted pose, whether its pelvis is the decoder's guess
        if self.layout.predicts_root:
            free = np.ones(len(emit), np.bool_) if waist is None else ~waist
        batch = Decoded(
            rot,
            con,
            root_mat,
            root_pos,
            pos,
            quat,
            first=np.array(firsts),
            neighbours=neighbours,
            free=free,
            kinds=s["kinds"][slots] if self._sites else None,
        )
        # The shown pose's passes, on the players' own state: gathered, stepped, put back.
        state = ShownState.of([s[n][slots] for n in SHOWN])
        shown = show(batch, state, self.cfg, self.pool)
        for n, a in zip(SHOWN, state.arrays(), strict=True):
            s[n][slots] = a
        wp, rotations, reach_limited = shown.positions, shown.rotations, shown.reach_limited
        limited = reach_limited.tolist()
        scale = np.array([p.calibration.scale for p, _, _ in emit], np.float32)
        positions = wp / scale[:, None, None]
        seqs, held = s["ring_seq"][k, slots].tolist(), s["ring_held"][k, slots].tolist()
        scales = scale.astype(np.float64).tolist()
        ahead = step_forecast(
            self.slots, [p for p, _, _ in emit], slots, positions, rotations, self.cfg.fps
        )
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
                ahead_ms=ahead[i],
            )
            for i, (p, sample, w) in enumerate(emit)
        ]
