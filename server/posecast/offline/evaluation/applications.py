"""The paper's Table 3 in spirit: sample selection for target hitting and collision avoidance.

* **Target hitting** (eq. 3): a kick clip; the kicking foot should hit a target
  placed low or high in front of the character at the kick's apex. The
  :class:`~posecast.online.engine.selectors.TargetSelector` runs for the whole clip; the
  error is the distance from the foot to the target at the apex frame.
* **Collision avoidance** (eq. 4): an obstacle (a box, as a sphere of ``radius``)
  beside the knee that travels with the body (the kick clip walks and turns, so a
  box fixed in the world would never be near the knee); the
  :class:`~posecast.online.engine.selectors.ObstacleSelector` is updated every frame with
  the obstacle's new place, which also exercises changing a selector at run time.
  The error is the share of frames in which the knee is inside the obstacle.

Each setting runs ``runs`` times with different latent seeds (all runs as players
of one engine, so they are batched), for each sample count.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from posecast.offline.dataset.frames import Frames
from posecast.online.engine.config import PAPER_LOOKAHEAD, EngineConfig
from posecast.online.engine.selectors import ObstacleSelector, SampleSelector, TargetSelector
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.auto import Backend
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot, from_character_frame, to_character_frame


@dataclass(frozen=True)
class Setting:
    name: str
    selector: SampleSelector
    joint: Joint


def _run(
    backend: Backend,
    fr: Frames,
    selector_at: Callable[[int], SampleSelector],
    samples: int,
    runs: int,
    seed0: int,
    latent_scale: float = 1.0,
) -> np.ndarray:
    """Emitted world positions ``(runs, T, 19, 3)`` of ``runs`` players on one clip."""
    # The paper's look-ahead: Table 3 replicates the paper's setting.
    cfg = EngineConfig(
        samples=samples, latent_scale=latent_scale, lookahead=PAPER_LOOKAHEAD, delayed_emission=True
    )
    engine = Engine(backend.decoder, backend.pool, cfg, runs, backend_name=backend.name)
    for r in range(runs):
        engine.add_player(str(r), seed=seed0 + r, selector=selector_at(0))
        # Every sample random, the first too (the engine makes it the prior's mean),
        # so the 1-sample row is a random sample, as in the paper.
        eps0 = np.random.default_rng(seed0 + r).standard_normal(engine.latent)
        engine.set_latents(str(r), eps0, 0)
    T = len(fr["features"])
    out = np.full((runs, T, 19, 3), np.nan, np.float32)
    for t in range(T + cfg.delay):
        if t < T:
            pos = fr["tracker_pos"][t].astype(np.float64)
            quat = fr["tracker_quat"][t].astype(np.float64)
            sel = selector_at(t)
            for r in range(runs):
                engine.push(str(r), TrackerFrame(t, pos, quat))
                engine.set_selector(str(r), sel)
        for pose in engine.tick().poses:
            if not pose.held and 0 <= pose.seq < T:
                out[int(pose.player), pose.seq] = pose.positions
    return out


def kick_targets(fr: Frames, foot: Joint) -> tuple[int, dict[str, tuple[float, float, float]]]:
    """The apex frame of the kick and a low and a high target in front of the body there."""
    gt = fr["positions"].astype(np.float64)
    apex = int(np.argmax(gt[:, foot, 1]))
    waist_pos = fr["tracker_pos"][apex, TrackerSlot.WAIST].astype(np.float64)
    waist_quat = fr["tracker_quat"][apex, TrackerSlot.WAIST].astype(np.float64)
    local_foot = to_character_frame(gt[apex, foot][None], waist_pos, waist_quat)[0]
    targets = {}
    for label, height in (("low", 0.45), ("high", 1.05)):
        local = np.array([local_foot[0], height, max(local_foot[2], 0.4)])
        world = from_character_frame(local, waist_pos, waist_quat)
        targets[label] = (float(world[0]), float(world[1]), float(world[2]))
    return apex, targets


def _constant(selector: SampleSelector) -> Callable[[int], SampleSelector]:
    def at(_t: int) -> SampleSelector:
        return selector

    return at


def table3(
    backend: Backend,
    kick: Frames,
    foot: Joint = Joint.RIGHT_FOOT,
    knee: Joint = Joint.LEFT_SHIN,
    sample_counts: Sequence[int] = (1, 10, 100, 1000),
    runs: int = 100,
    latent_scale: float = 1.0,
) -> dict[str, Any]:
    """Mean and std over ``runs`` of the target error (m) and the collision share, with
    the pool's latents ``latent_scale * eps`` (``EngineConfig.latent_scale``: above 1 a
    wider pool, for applications that look for rarer poses than streaming does)."""
    apex, targets = kick_targets(kick, foot)
    gt = kick["positions"].astype(np.float64)
    wq = kick["tracker_quat"][:, TrackerSlot.WAIST].astype(np.float64)
    wp = kick["tracker_pos"][:, TrackerSlot.WAIST].astype(np.float64)
    # The obstacle: 5 cm outside the knee's median place in the body frame, r = 20 cm.
    local_knee = np.median(to_character_frame(gt[:, knee][:, None], wp, wq)[:, 0], axis=0)
    side = 1.0 if knee.name.startswith("LEFT") else -1.0
    obstacle_local = local_knee + np.array([0.05 * side, 0.0, 0.0])
    obstacles = np.stack(
        [from_character_frame(obstacle_local, wp[t], wq[t]) for t in range(len(gt))]
    )
    radius = 0.2
    gt_share = float((np.linalg.norm(gt[:, knee] - obstacles, axis=-1) < radius).mean())
    rows: dict[str, Any] = {}
    for n in sample_counts:
        row: dict[str, Any] = {}
        for label, target in targets.items():
            out = _run(
                backend,
                kick,
                _constant(TargetSelector(foot, target, 0.0)),
                n,
                runs,
                1000 * n,
                latent_scale,
            )
            err = np.linalg.norm(out[:, apex, foot] - np.asarray(target), axis=-1)
            row[f"{label}_kick_m"] = {"mean": float(err.mean()), "std": float(err.std())}

        def obstacle_at(t: int) -> SampleSelector:
            o = obstacles[min(t, len(obstacles) - 1)]
            return ObstacleSelector(knee, (float(o[0]), float(o[1]), float(o[2])), radius)

        out = _run(backend, kick, obstacle_at, n, runs, 7000 * n, latent_scale)
        inside = np.linalg.norm(out[:, :, knee] - obstacles[None], axis=-1) < radius
        share = inside.mean(axis=1)
        row["collision_share"] = {"mean": float(share.mean()), "std": float(share.std())}
        rows[str(n)] = row
    return {
        "backend": backend.name,
        "apex_frame": apex,
        "targets_m": targets,
        "obstacle_local_m": obstacle_local.tolist(),
        "obstacle_radius_m": radius,
        "ground_truth_collision_share": gt_share,
        "runs": runs,
        "latent_scale": latent_scale,
        "samples": rows,
    }
