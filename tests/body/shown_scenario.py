"""A seeded tick-by-tick scenario that runs every pass of the shown pose, for the golden
parity test (``test_shown_golden.py``).

It uses only the engine's public API (``load_backend``, ``Engine``, ``TrackerFrame``,
``Calibration``, ``TrackerSet``), so the same file runs against an older tree:
``tests/body/data/shown_golden.npz`` was written by this module's ``main`` on the
parent commit of the body pipeline (``d0038e4``), before the passes moved to
``posecast.body``::

    git worktree add /tmp/body-old d0038e4
    PYTHONPATH=/tmp/body-old/server:. python -m tests.body.shown_scenario OUT.npz

A pass that changes the streamed poses on purpose rewrites it on its own tree
(``PYTHONPATH=server:. python -m tests.body.shown_scenario
tests/body/data/shown_golden.npz``; last: the planted toes, ``posecast.body.plant``).

What it exercises, per layout (4 points, headset only, tracker sets): transitions and
their blends (a low outlier factor), the pelvis smoothing, a guessed pelvis's lean and
reach (with a controller thrown out of reach: ``reach_limited``), feet pushed under
the floor (the floor pass and the swing clearance), a twisting waist (the legs apart),
rest frames before a late first frame, held frames over a gap, a calibration scale and
a recalibration mid-stream, a player joining late and one leaving (a slot swap), and on
the ``sites`` engine positional feet and knees (the leg pass) and IMUs.
"""

from __future__ import annotations

import sys
from functools import cache
from typing import Any

import numpy as np

from posecast.geometry.rotations import axis_angle_mat, mat2quat, mat2r6d, quat2mat, r6d2mat
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.evaluation.runner import clip_tracks
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.calibration import Calibration
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.auto import load_backend
from posecast.skeleton import Joint
from posecast.tracking.layouts import Layout
from posecast.tracking.sites import TrackerSet

FPS = 60.0
TICKS = 21
LAYOUTS = ("hmd3+waist", "hmd3", "sites")
BACKENDS = ("native", "onnx")
# Per player: the walk's seed, the tracker set (sites), and its events.
SETS = ("4p", "3p", "8p", "3p+2i")
SET_TEXT = {
    "3p": "head,left_hand,right_hand",
    "4p": "head,left_hand,right_hand,waist",
    "8p": "head,left_hand,right_hand,waist,left_foot,right_foot,left_knee,right_knee",
    "3p+2i": "head,left_hand,right_hand,left_foot:imu,right_foot:imu",
}
CFG = {
    "samples": 6,
    "lookahead": 4,
    "delayed_emission": True,  # the golden streams were recorded with the paper's delay
    "transition_frames": 3,
    "outlier_factor": 0.3,  # transitions often, so their blends are streamed
}


@cache
def _walk(seed: int, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """The walk of ``seed`` in the engine's rows of ``layout`` (``sites``: the set of the
    player, :data:`SETS`): positions ``(T, rows, 3)`` and orientations ``(T, rows, 4)``."""
    fr = derive_frames(walk_clip(seconds=TICKS / FPS + 0.1, fps=FPS, seed=seed))
    if layout == "sites":
        tr = clip_tracks(fr, FPS, TrackerSet.parse(SET_TEXT[SETS[seed]]), seed=seed)
        return tr.values.astype(np.float64), tr.quat.astype(np.float64)
    return fr["tracker_pos"].astype(np.float64), fr["tracker_quat"].astype(np.float64)


def _frame(seed: int, layout: str, t: int) -> TrackerFrame:
    """Player ``seed``'s frame ``t``, with its events (see the module docstring)."""
    pos, quat = (a[t].copy() for a in _walk(seed, layout))
    if seed == 0:  # feet under the floor: the floor pass and the swing clearance
        pos[:, 1] -= 0.08
    if seed == 1:  # a calibration scale 1.2 (the user is smaller)
        pos /= 1.2
    if seed == 2 and 8 <= t < 12:  # the right controller thrown 2 m away
        pos[2] += [2.0, 0.3, 0.0]
    if seed == 3 and layout != "sites":  # the waist twists back and forth
        angle = 1.1 * np.sin(2 * np.pi * 1.5 * t / FPS)
        turn = axis_angle_mat(np.array([[0.0, 1.0, 0.0]]), np.array([angle]))[0]
        quat[3] = mat2quat(turn @ quat2mat(quat[3]))
    return TrackerFrame(t, pos, quat)


# A crossing step, for every player at once: over these ticks the decoder is told the
# left foot is planted (its contact held at 1) while both legs swing sideways under the
# pelvis (the thighs turned about its forward axis), so the right leg sweeps into the
# held left foot: the legs-apart pass must move it.
CROSSING = (7, 15)
CROSSING_RAD = 0.5
_THIGH_ROWS = [int(Joint.LEFT_THIGH) - 1, int(Joint.RIGHT_THIGH) - 1]


class CrossingDecoder:
    """A backend's decoder whose outputs take the :data:`CROSSING` step (the same change
    on every row, blends included, so it is the same however the rows are batched)."""

    def __init__(self, inner: Any) -> None:
        self.inner, self.tick = inner, 0
        self.name, self.meta, self.cache_width = inner.name, inner.meta, inner.cache_width

    def cache_latents(self, eps: np.ndarray) -> np.ndarray:
        out: np.ndarray = self.inner.cache_latents(eps)
        return out

    def step(self, features: Any, group: int, cache: Any, h: Any, out: Any) -> None:
        self.inner.step(features, group, cache, h, out)
        start, end = CROSSING
        if not start <= self.tick < end:
            return
        angle = CROSSING_RAD * min(1.0, (self.tick - start + 1) / 4)
        turn = axis_angle_mat(np.array([[0.0, 0.0, 1.0]]), np.array([angle]))[0]
        rot = out["rotations"].reshape(len(out["rotations"]), -1, 6)
        thighs = r6d2mat(rot[:, _THIGH_ROWS].astype(np.float64))
        rot[:, _THIGH_ROWS] = mat2r6d(turn @ thighs).astype(np.float32)
        out["contacts"][:, 0] = 1.0


def run(backend: str, layout: str) -> dict[str, np.ndarray]:
    """Every pose the engine streams over :data:`TICKS` ticks, in order."""
    cfg = EngineConfig(**CFG)  # type: ignore[arg-type]
    b = load_backend(backend, layout, threads=1, cfg=cfg)
    if b.name != backend:
        raise RuntimeError(f"{backend} fell back to {b.name}")
    decoder = CrossingDecoder(b.decoder)
    engine = Engine(decoder, b.pool, cfg, capacity=2, backend_name=b.name)

    def add(seed: int, calibration: Calibration | None = None) -> None:
        ts = TrackerSet.parse(SET_TEXT[SETS[seed]]) if layout == "sites" else None
        engine.add_player(str(seed), seed=seed, calibration=calibration, tracker_set=ts)

    add(0)
    add(1, Calibration(scale=1.2))
    add(2)
    out: dict[str, list[object]] = {
        k: [] for k in ("positions", "rotations", "contacts", "scale", "meta")
    }
    for t in range(TICKS):
        if t == 5:
            add(3)  # joins late (its first tick is a real frame)
        if t == 12:
            engine.set_calibration("1", Calibration(scale=1.1))
        if t == 20:
            engine.remove_player("0")  # the last slot moves into slot 0
        for seed in range(4):
            if str(seed) not in engine.players:
                continue
            if seed == 2 and (t < 3 or 13 <= t < 17):
                continue  # rest frames before its first one, then a gap: held frames
            f = _frame(seed, layout, t)
            if seed == 1 and t >= 12:
                f = TrackerFrame(f.seq, f.pos * 1.2 / 1.1, f.quat)
            engine.push(str(seed), f)
        decoder.tick = t
        for p in engine.tick().poses:
            out["positions"].append(p.positions)
            out["rotations"].append(p.rotations)
            out["contacts"].append(p.contacts)
            out["scale"].append(p.scale)
            out["meta"].append(
                [t, int(p.player), p.seq, p.sample, p.transitioning, p.held, p.reach_limited]
            )
    return {
        "positions": np.array(out["positions"], np.float32),
        "rotations": np.array(out["rotations"], np.float32),
        "contacts": np.array(out["contacts"], np.float32),
        "scale": np.array(out["scale"], np.float64),
        "meta": np.array(out["meta"], np.int64),
    }


def scenario() -> dict[str, np.ndarray]:
    """:func:`run` on every backend of :data:`BACKENDS` and layout of :data:`LAYOUTS`,
    keyed ``backend/layout/field``."""
    return {
        f"{backend}/{layout}/{k}": v
        for backend in BACKENDS
        for layout in LAYOUTS
        for k, v in run(backend, Layout(layout)).items()
    }


def machine() -> str:
    """The CPU features numpy dispatches on and the native kernels' level: where these
    differ from the golden file's, its last bits (and so SSI's choices) may too."""
    from numpy._core._multiarray_umath import __cpu_features__

    try:
        from posecast import _native  # type: ignore[attr-defined]

        level = str(_native.isa())
    except ImportError:
        level = "none"
    return ",".join(sorted(k for k, on in __cpu_features__.items() if on)) + f"; native {level}"


def main(path: str) -> None:
    arrays = scenario()
    np.savez_compressed(path, machine=np.array(machine()), **arrays)
    print(path, machine(), {k: len(v) for k, v in arrays.items() if k.endswith("meta")})


if __name__ == "__main__":
    main(sys.argv[1])
