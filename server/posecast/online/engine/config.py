"""Engine settings. Built once at the edge (CLI/env) and passed down; immutable."""

from __future__ import annotations

from dataclasses import dataclass

from posecast.body.ik import MAX_DRIFT_M, RELEASE_FRAMES
from posecast.body.upper_ik import WRIST_ELBOW_SHARE
from posecast.errors import ConfigError

# The most latent samples per player, N. The engine's buffers hold (lookahead + 2) x
# players x N GRU states of 128 floats; past a few thousand one player costs gigabytes
# and a tick takes longer than its period anyway (the paper and the server use 100;
# eval-apps goes to 1000).
MAX_SAMPLES = 4096
# The paper's look-ahead tau (Sec. 3.2.4), with delayed emission: poses 10 frames late.
PAPER_LOOKAHEAD = 10


@dataclass(frozen=True)
class EngineConfig:
    """Sample selection and interpolation settings (paper Sec. 3.2).

    Attributes:
        samples: latent samples per player, ``N`` (default 100).
        lookahead: ``tau``, frames of look-ahead (paper Sec. 3.2.4): a transition to a
            better sample, detected at the newest frame ``n``, has its first blended
            frame at ``n - min(tau, T) + 1``. With ``delayed_emission`` the engine shows
            frame ``n - tau`` (the paper: the blend is done before the outlier would
            show); without it (the default) it shows frame ``n``, so ``tau`` is only
            how far the blend has got at the frame of detection, ``min(tau, T) / T``
            (default 0, chosen on the validation split, docs/latency.md).
        delayed_emission: emit frame ``n - tau`` at tick ``n`` (the paper's setting,
            with ``lookahead=10``: poses lag their frames by ``tau`` ticks) instead of
            frame ``n`` (default off: every pose is the newest frame's). :attr:`delay`
            is the lag either way.
        transition_frames: ``T``, frames a transition to a better sample takes (10).
        outlier_factor: the current sample is an outlier when ``R_c > factor * r``,
            ``r = median(R) - min(R)`` (2.0, the paper's trimmed estimator).
        outlier_baseline: ``"zero"`` for that rule, ``"min"`` to measure from the best
            sample, ``R_c - min(R) > factor * r`` (see :mod:`posecast.online.engine.selectors`).
        ik_release_frames: frames to blend a released foot back to the network (20).
        ik_max_drift_m: release a foot lock early once the network's ankle is this far
            from it, then lock again where the foot is (0.05 m; both chosen on the
            validation split, see docs/evaluation.md; ``None`` keeps every lock for the
            whole predicted contact, as the paper).
        stale_after_frames: frames without input before a player is marked stale (30).
        waist_filter_hz: cutoff of the waist-orientation low-pass, ``None`` for off.
        fps: tick rate the model was trained at (60).
        upper_body_ik: put the shown pose's head on the headset and hands on the
            controllers (:mod:`posecast.body.upper_ik`; default on, off for
            research evaluation of the network's own upper body).
        floor_ik: lift a shown foot that is below the floor (``y = 0``) onto it
            (:func:`posecast.body.ik.floor_ik`; default on, off for research
            evaluation of the network's own legs). With it, the swing clearance:
        swing_clearance: lift a shown toe to the height real toes keep at its
            horizontal speed (:mod:`posecast.body.clearance`; default on,
            chosen on the validation split, docs/evaluation.md, "Feet"; only with
            ``floor_ik``).
        planted_toes: a shown toe in predicted contact near the floor slides at most
            1 m/s, trailing the network's by up to 4 cm (:mod:`posecast.body.plant`;
            default on, chosen on the validation split, docs/latency.md, "Skating
            toes"; only with ``floor_ik``).
        wrist_elbow: the share of each shown elbow's placement that comes from its
            controller's rotation (a straight wrist), the rest from the network's
            elbow (0.75, chosen on the validation split; 0 for the network's alone;
            :func:`posecast.body.upper_ik.solve_upper_body`).
        hand_reach: move a pelvis that is the decoder's guess (no waist tracker)
            toward a controller beyond the arm's reach, horizontally, before the feet
            are planted (:func:`posecast.body.upper_ik.reach_root`; default
            on, with ``upper_body_ik``).
        torso_span: move a body whose pelvis is the decoder's guess along the line
            from its spine to the headset until the spine is as far from the headset
            as the network's own head is from it (:data:`~posecast.online.engine.
            upper_ik.SPAN_SHARE` of that gap), so that the spine chain reaches the
            headset with the network's torso instead of folding it, as part of the
            hand reach's move (:func:`posecast.body.upper_ik.reach_root`;
            default on, with ``hand_reach``; chosen on the validation split).
        legs_apart: where the display contact IK draws one leg into the other (a
            held foot the other leg swings past), the held foot gives way toward the
            network's own ankle just as far as keeps the legs apart
            (:mod:`posecast.body.apart`; default on, off for research
            evaluation; chosen on the validation split, docs/evaluation.md, "Legs
            apart").
        pelvis_lean: turn a pelvis that is the decoder's guess (no waist tracker)
            about itself so that the line from it to the network's head points at the
            headset, the upper body with it and the legs following the hips, before
            the hand reach and the feet (:func:`posecast.body.upper_ik.lean_root`;
            default on, with ``upper_body_ik``; chosen on the validation split).
        elbow_hinge: turn the shown upper arms and forearms so each elbow bends as
            a hinge about a fixed axis in its upper arm's frame, no joint moving
            (after the upper-body pass; :func:`posecast.body.hinge.hinge_elbows`;
            default on, off for research evaluation).
        knee_hinge: turn the shown thighs and shins so each knee bends as a hinge
            about its thigh's axis, no joint moving (:mod:`posecast.body.hinge`;
            default on, off for research evaluation).
        pelvis_smoothing: build the shown pose on the pelvis averaged over frames
            ``e - 1, e, e + 1`` (weights 1, 2, 1; needs ``delay >= 1``, adds no lag;
            :mod:`posecast.body.pelvis`): default on, chosen on the validation
            split (docs/evaluation.md, "Jitter"); off for research evaluation.
        floor_select: SSI leaves out of the pool, frame by frame, every sample with a
            foot deeper below the floor than the floor pass lifts (it is never chosen,
            and a current sample that sinks that deep is left); needs ``floor_ik``;
            default on, off for research evaluation (docs/evaluation.md, "SSI and the
            floor").
        latent_scale: the pool's latents are ``latent_scale * eps``, ``eps ~ N(0, I)``
            (1.0: the prior; below 1 a truncated pool, nearer the mean).
        home_factor: the threshold at which a player returns to sample 0, the prior's
            mean (:class:`~posecast.online.engine.selectors.AnomalySelector`'s ``home``,
            capped at ``outlier_factor``); 1.0, chosen on the validation split
            (docs/evaluation.md); ``None`` for the paper's selector.
    """

    samples: int = 100
    lookahead: int = 0
    delayed_emission: bool = False
    transition_frames: int = 10
    outlier_factor: float = 2.0
    outlier_baseline: str = "zero"
    ik_release_frames: int = RELEASE_FRAMES
    ik_max_drift_m: float | None = MAX_DRIFT_M
    stale_after_frames: int = 30
    waist_filter_hz: float | None = None
    fps: float = 60.0
    upper_body_ik: bool = True
    floor_ik: bool = True
    swing_clearance: bool = True
    planted_toes: bool = True
    knee_hinge: bool = True
    elbow_hinge: bool = True
    wrist_elbow: float = WRIST_ELBOW_SHARE
    hand_reach: bool = True
    torso_span: bool = True
    legs_apart: bool = True
    pelvis_lean: bool = True
    pelvis_smoothing: bool = True
    floor_select: bool = True
    latent_scale: float = 1.0
    home_factor: float | None = 1.0

    @property
    def delay(self) -> int:
        """Ticks between a frame's arrival and its pose's emission: ``lookahead`` with
        ``delayed_emission``, else 0 (the server's welcome ``lookahead_frames``)."""
        return self.lookahead if self.delayed_emission else 0

    @property
    def reaches(self) -> bool:
        """Whether a guessed pelvis is moved toward out-of-reach trackers before the
        feet are planted (``hand_reach``, part of the upper-body pass)."""
        return self.upper_body_ik and self.hand_reach

    @property
    def leans(self) -> bool:
        """Whether a guessed pelvis leans toward the headset before the hand reach and
        the feet (``pelvis_lean``, part of the upper-body pass)."""
        return self.upper_body_ik and self.pelvis_lean

    def __post_init__(self) -> None:
        if not 1 <= self.samples <= MAX_SAMPLES:
            raise ConfigError(f"samples must be in [1, {MAX_SAMPLES}]")
        if self.lookahead < 0 or self.transition_frames < 1:
            raise ConfigError("lookahead must be >= 0 and transition_frames >= 1")
        if self.outlier_factor <= 0 or self.stale_after_frames < 1:
            raise ConfigError("outlier_factor must be > 0 and stale_after_frames >= 1")
        if self.outlier_baseline not in ("min", "zero"):
            raise ConfigError("outlier_baseline must be 'min' or 'zero'")
        if not self.latent_scale > 0:
            raise ConfigError("latent_scale must be positive")
        if self.home_factor is not None and not 0.0 <= self.home_factor < float("inf"):
            raise ConfigError("home_factor must be a finite number >= 0")
        if not 0.0 <= self.wrist_elbow <= 1.0:
            raise ConfigError("wrist_elbow must be a share between 0 and 1")
        if self.waist_filter_hz is not None and not self.waist_filter_hz > 0:
            raise ConfigError("waist_filter_hz must be positive")
