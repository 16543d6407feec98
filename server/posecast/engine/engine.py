"""The SSI engine: every player advances one frame per tick, all in one batch.

Per tick, for all ``P`` players x ``N`` samples at once:

1. tracker frames -> calibrated positions -> features ``(P, 24)``
2. one decoder call on ``P*N`` rows -> rotations, contacts, next hidden states
3. FK with the root from the waist tracker, then per-sample contact IK
4. anomaly error ``R`` of every sample, and each player's selector decides whether
   its current sample must give way (detected at frame ``n``, the newest)
5. emit frame ``n - tau`` per player: the current sample's pose, or during a
   transition the decoder re-run on the interpolated latent and hidden state
   (one more batched call), then that player's own display IK

The engine is pure: frames go in with :meth:`Engine.push`, :meth:`Engine.tick`
returns poses and events. No sockets, no clocks, no threads.

Look-ahead (paper Sec. 3.2.4): each player keeps a ring of ``tau + 1`` frames of
inputs, pre-step hidden states and raw outputs for all samples. An outlier found at
frame ``n`` starts a transition whose first interpolated frame is
``n - min(tau, T) + 1``, none of which has been emitted yet; with ``tau = T`` the
new sample is fully in place exactly at the frame where the outlier would have shown.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from posecast.engine.anomaly import AnomalyScorer
from posecast.engine.calibration import Calibration, WaistFilter
from posecast.engine.config import EngineConfig
from posecast.engine.ik import ContactIK
from posecast.engine.kinematics32 import fk32
from posecast.engine.selectors import AnomalySelector, Selector
from posecast.engine.slots import SlotArrays
from posecast.geometry.kinematics import fk_positions
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.inference.artifact import Artifact
from posecast.skeleton import NUM_JOINTS, REST_PELVIS_HEIGHT_M, reference_offsets
from posecast.tracking import NUM_FEATURES, TRACKER_JOINT_INDEX, TrackerSlot, tracker_features

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TrackerFrame:
    """One frame from a headset: 4 trackers in slot order, world metres, xyzw."""

    seq: int
    pos: F64  # (4, 3)
    quat: F64  # (4, 4)


@dataclass(frozen=True)
class PoseOut:
    """A reconstructed pose, ``tau`` frames behind the newest input."""

    player: str
    seq: int  # seq of the tracker frame this pose is for
    positions: F32  # (19, 3) world metres, at the user's own scale
    rotations: F32  # (19, 4) world xyzw
    contacts: F32  # (2,)
    sample: int  # the latent sample shown (the destination during a transition)
    transitioning: bool
    held: bool  # the input was held over a missing frame


@dataclass(frozen=True)
class EngineEvent:
    kind: str  # "stale" | "active"
    player: str


@dataclass
class TickResult:
    poses: list[PoseOut]
    events: list[EngineEvent]
    transitions: int  # transitions started this tick, all players


@dataclass
class _Transition:
    src: int
    dst: int
    start: int  # first frame with a weight above zero


@dataclass
class _Player:
    id: str
    slot: int
    selector: Selector
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
    display_ik: ContactIK = field(default_factory=lambda: ContactIK.zeros(1))


class Engine:
    """Batched SSI for many players. See the module docstring for one tick's steps."""

    def __init__(
        self,
        decoder: Artifact,
        scorer: AnomalyScorer,
        cfg: EngineConfig | None = None,
        capacity: int = 8,
    ) -> None:
        self.cfg = cfg or EngineConfig()
        self.decoder = decoder
        self.scorer = scorer
        mc = decoder.meta["model_config"]
        self.latent, self.hidden = int(mc["latent"]), int(mc["hidden"])
        N, L = self.cfg.samples, self.cfg.lookahead + 1
        self.slots = SlotArrays(
            {
                "eps": ((N, self.latent), np.float32),
                "h": ((N, self.hidden), np.float32),
                "ik_locked": ((N, 2), np.bool_),
                "ik_lock_pos": ((N, 2, 3), np.float64),
                "ik_release": ((N, 2), np.int64),
                "ik_suppressed": ((N, 2), np.bool_),
                "ring_h": ((L, N, self.hidden), np.float32),  # hidden state before frame
                "ring_rot": ((L, N, 108), np.float32),
                "ring_con": ((L, N, 2), np.float32),
                "ring_x": ((L, NUM_FEATURES), np.float32),
                "ring_pos": ((L, 4, 3), np.float64),  # calibrated tracker positions
                "ring_quat": ((L, 4, 4), np.float64),
                "ring_seq": ((L,), np.int64),
                "ring_held": ((L,), np.bool_),
            },
            capacity,
        )
        self.players: dict[str, _Player] = {}
        self._order: list[str] = []  # player id per slot

    # --- membership -----------------------------------------------------------------

    def add_player(
        self,
        player: str,
        seed: int,
        selector: Selector | None = None,
        calibration: Calibration | None = None,
    ) -> None:
        """Join ``player``. Its ``N`` latent samples are drawn from ``seed``; sample 0 is
        the prior's mean (``eps = 0``) and starts as the current sample."""
        if player in self.players:
            raise ValueError(f"player {player!r} is already in the engine")
        slot = self.slots.add()
        eps = np.random.default_rng(seed).standard_normal((self.cfg.samples, self.latent))
        eps[0] = 0.0
        self.slots["eps"][slot] = eps
        wf = (
            WaistFilter(self.cfg.waist_filter_hz, self.cfg.fps)
            if self.cfg.waist_filter_hz
            else None
        )
        self.players[player] = _Player(
            player,
            slot,
            selector or AnomalySelector(self.cfg.outlier_factor, self.cfg.outlier_baseline),
            calibration or Calibration(),
            wf,
            display_ik=ContactIK.zeros(1, self.cfg.ik_release_frames, self.cfg.ik_max_drift_m),
        )
        self._order.append(player)

    def remove_player(self, player: str) -> None:
        p = self.players.pop(player)
        moved = self.slots.remove(p.slot)
        last_id = self._order.pop()
        if moved is not None:
            self._order[p.slot] = last_id
            self.players[last_id].slot = p.slot

    def set_selector(self, player: str, selector: Selector) -> None:
        self.players[player].selector = selector

    def set_calibration(self, player: str, calibration: Calibration) -> None:
        self.players[player].calibration = calibration

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
            return TickResult([], [], 0)
        events = self._gather_inputs()
        s = self.slots
        L = self.cfg.lookahead + 1
        ring = np.array([self.players[pid].frames % L for pid in self._order])
        rows = np.arange(P)
        x = s.view("ring_x")[rows, ring]  # (P, 24)
        pos = s.view("ring_pos")[rows, ring]  # (P, 4, 3)
        quat = s.view("ring_quat")[rows, ring]  # (P, 4, 4)
        h = s.view("h")  # (P, N, H)
        s.view("ring_h")[rows, ring] = h

        rot, con, h_new = self.decoder.run(
            features=np.repeat(x, N, axis=0),
            z=s.view("eps").reshape(P * N, self.latent),
            h=h.reshape(P * N, self.hidden),
        )
        h[...] = h_new.reshape(P, N, self.hidden)
        s.view("ring_rot")[rows, ring] = rot.reshape(P, N, 108)
        s.view("ring_con")[rows, ring] = con.reshape(P, N, 2)

        waist_pos, waist_quat = pos[:, TrackerSlot.WAIST], quat[:, TrackerSlot.WAIST]  # (P, ...)
        _, wp = fk32(
            rot,
            np.repeat(quat2mat(waist_quat).astype(np.float32), N, axis=0),
            np.repeat(waist_pos.astype(np.float32), N, axis=0),
            False,
        )
        ik = ContactIK(
            s.view("ik_locked").reshape(P * N, 2),
            s.view("ik_lock_pos").reshape(P * N, 2, 3),
            s.view("ik_release").reshape(P * N, 2),
            self.cfg.ik_release_frames,
            s.view("ik_suppressed").reshape(P * N, 2),
            self.cfg.ik_max_drift_m,
        )
        ik.step(None, wp, con)
        scores = self.scorer.score(wp, waist_pos, waist_quat, repeat=N).reshape(P, N)
        wp = wp.reshape(P, N, -1, 3)

        started = 0
        for i, pid in enumerate(self._order):
            started += self._select(self.players[pid], scores[i], wp[i])
        poses = self._emit()
        for pid in self._order:
            self.players[pid].frames += 1
        return TickResult(poses, events, started)

    def _gather_inputs(self) -> list[EngineEvent]:
        """Write this frame's inputs into every player's ring; hold missing frames."""
        L = self.cfg.lookahead + 1
        events: list[EngineEvent] = []
        s = self.slots
        for pid in self._order:
            p = self.players[pid]
            k = p.frames % L
            frame, held = p.pending, False
            if frame is None:
                held = True
                p.missing += 1
                if p.missing >= self.cfg.stale_after_frames and not p.stale:
                    p.stale = True
                    events.append(EngineEvent("stale", pid))
            else:
                p.missing = 0
                if p.stale:
                    p.stale = False
                    events.append(EngineEvent("active", pid))
            p.pending = None
            prev_k = (p.frames - 1) % L
            if frame is None and p.last is None:
                # Nothing ever arrived: stand still at the origin in the rest pose.
                frame = TrackerFrame(-1, _rest_trackers(), _identity_quats())
            if frame is None:
                s["ring_x"][p.slot, k] = s["ring_x"][p.slot, prev_k]
                s["ring_pos"][p.slot, k] = s["ring_pos"][p.slot, prev_k]
                s["ring_quat"][p.slot, k] = s["ring_quat"][p.slot, prev_k]
                s["ring_seq"][p.slot, k] = s["ring_seq"][p.slot, prev_k]
            else:
                q = np.array(frame.quat, dtype=np.float64)
                if p.waist_filter is not None:
                    q[TrackerSlot.WAIST] = p.waist_filter(q[TrackerSlot.WAIST])
                cal = p.calibration.apply(np.asarray(frame.pos, dtype=np.float64), q)
                prev = s["ring_pos"][p.slot, prev_k] if p.last is not None else cal
                s["ring_x"][p.slot, k] = tracker_features(
                    cal, prev, q[TrackerSlot.WAIST], self.cfg.fps
                )
                s["ring_pos"][p.slot, k] = cal
                s["ring_quat"][p.slot, k] = q
                s["ring_seq"][p.slot, k] = frame.seq
                if frame.seq >= 0:
                    p.last = frame
            s["ring_held"][p.slot, k] = held
        return events

    def _select(self, p: _Player, scores: F64, positions: F32) -> int:
        """Run the player's selector at the newest frame; plan a transition if asked."""
        if p.plan is not None:
            return 0
        best = p.selector.choose(p.current, scores, positions)
        if best is None or best == p.current:
            return 0
        n = p.frames
        start = n - min(self.cfg.lookahead, self.cfg.transition_frames) + 1
        p.plan = _Transition(p.current, best, start)
        p.current = best
        p.transitions += 1
        return 1

    def _emit(self) -> list[PoseOut]:
        tau, T, L = self.cfg.lookahead, self.cfg.transition_frames, self.cfg.lookahead + 1
        s = self.slots
        emit: list[tuple[_Player, int, int, float]] = []  # player, ring index, sample, weight
        for pid in self._order:
            p = self.players[pid]
            e = p.frames - tau
            if e < 0:
                continue
            k = e % L
            if p.plan is None or e < p.plan.start:
                sample = p.plan.src if p.plan is not None else p.current
                emit.append((p, k, sample, 0.0))
                continue
            w = min(1.0, (e - p.plan.start + 1) / T)
            emit.append((p, k, p.plan.dst, w))
        if not emit:
            return []
        rot = np.empty((len(emit), 108), np.float32)
        con = np.empty((len(emit), 2), np.float32)
        interp = [i for i, (_, _, _, w) in enumerate(emit) if 0.0 < w < 1.0]
        for i, (p, k, sample, _) in enumerate(emit):
            rot[i] = s["ring_rot"][p.slot, k, sample]
            con[i] = s["ring_con"][p.slot, k, sample]
        if interp:
            xs, zs, hs = [], [], []
            for i in interp:
                p, k, _, w = emit[i]
                assert p.plan is not None
                eps, hr = s["eps"][p.slot], s["ring_h"][p.slot, k]
                zs.append((1 - w) * eps[p.plan.src] + w * eps[p.plan.dst])
                hs.append((1 - w) * hr[p.plan.src] + w * hr[p.plan.dst])
                xs.append(s["ring_x"][p.slot, k])
            r, c, _ = self.decoder.run(
                features=np.asarray(xs, np.float32),
                z=np.asarray(zs, np.float32),
                h=np.asarray(hs, np.float32),
            )
            rot[interp], con[interp] = r, c
        for p, _, _, w in emit:
            if p.plan is not None and w >= 1.0:
                p.plan = None
        slots = np.array([p.slot for p, *_ in emit])
        ks = np.array([k for _, k, _, _ in emit])
        pos = s["ring_pos"][slots, ks]
        quat = s["ring_quat"][slots, ks]
        wm, wp = fk32(
            rot,
            quat2mat(quat[:, TrackerSlot.WAIST]).astype(np.float32),
            pos[:, TrackerSlot.WAIST].astype(np.float32),
        )
        assert wm is not None
        out = []
        for i, (p, k, sample, w) in enumerate(emit):
            p.display_ik.step(wm[i : i + 1], wp[i : i + 1], con[i : i + 1])
            scale = p.calibration.scale
            out.append(
                PoseOut(
                    player=p.id,
                    seq=int(s["ring_seq"][p.slot, k]),
                    positions=(wp[i] / scale).astype(np.float32),
                    rotations=mat2quat(wm[i]).astype(np.float32),
                    contacts=con[i].copy(),
                    sample=sample,
                    transitioning=0.0 < w < 1.0,
                    held=bool(s["ring_held"][p.slot, k]),
                )
            )
        return out


def _rest_trackers() -> F64:
    """Tracker positions of the reference body standing in its rest pose at the origin."""
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    pos = fk_positions(eye, np.array([0.0, REST_PELVIS_HEIGHT_M, 0.0]), reference_offsets())
    return pos[list(TRACKER_JOINT_INDEX)]


def _identity_quats() -> F64:
    q = np.zeros((4, 4))
    q[:, 3] = 1.0
    return q


def load_engine(
    cfg: EngineConfig | None = None, models_dir: str | None = None, threads: int = 1
) -> Engine:
    """An engine on the shipped models (or those in ``models_dir``)."""
    from posecast.inference.artifact import load_artifact

    decoder = load_artifact("cvae_decoder", models_dir, threads=threads)
    scorer = AnomalyScorer(load_artifact("anomaly", models_dir, threads=threads))
    return Engine(decoder, scorer, cfg)
