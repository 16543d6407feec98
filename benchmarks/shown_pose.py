"""The shown pose's passes in C against numpy: ``python benchmarks/shown_pose.py
[--players 1,10,25,50,100] [--ticks 300]``.

Two engines on the ``native`` backend, identical but for where the upper-body pass and
the hinges (knees, elbows) of the shown poses run: in C (``NativePool.upper_body`` and
``hinge``, ``pc_upper.c``, what the backend serves) or in numpy (the references,
``posecast.body.passes.NumpyPasses``). Both tick in turn, tick by tick,
in one process on the generated walk, so machine load hits both alike; prints the
whole tick's p50 and p90 for each and their ratio, and the passes alone on ``E`` shown
poses. It also checks that the two engines stream the same poses.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from posecast.body.hinge import ELBOW_LIMBS, KNEE_LIMBS, Limbs
from posecast.body.passes import NumpyPasses
from posecast.offline.evaluation.engine_speed import bench_frames
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine
from posecast.tracking.layouts import Layout


class NumpyShownPool:
    """A native pool whose shown pose's upper-body pass and hinges are the numpy
    references (:class:`posecast.body.passes.NumpyPasses`)."""

    def __init__(self, pool: Any) -> None:
        self.pool, self.threshold_m, self.numpy = pool, pool.threshold_m, NumpyPasses()

    def step(self, *args: Any) -> Any:
        return self.pool.step(*args)

    def emit(self, *args: Any) -> Any:
        return self.pool.emit(*args)

    def upper_body(self, *args: Any) -> Any:
        return self.numpy.upper_body(*args)

    def hinge(self, positions: Any, rotations: Any, limbs: Limbs) -> None:
        self.numpy.hinge(positions, rotations, limbs)


def _passes_alone(pool: Any, E: int, repeats: int = 200) -> tuple[float, float]:
    """Milliseconds per call of the three passes on ``E`` poses: C, numpy."""
    eng = load_engine(EngineConfig(samples=1), None, 1, Layout.HMD3_WAIST, "native")
    pos, quat = bench_frames()
    rng = np.random.default_rng(0)
    for p in range(E):
        eng.add_player(f"p{p}", seed=p)
    for t in range(20):  # a few ticks for real shown poses
        for p in range(E):
            k = int(rng.integers(len(pos)))
            eng.push(f"p{p}", TrackerFrame(t, pos[k], quat[k]))
        shown = eng.tick().poses
    wp = np.stack([s.positions for s in shown]).astype(np.float32)
    rot = np.stack([s.rotations for s in shown]).astype(np.float32)
    picks = rng.integers(len(pos), size=len(wp))
    tp, tq = pos[picks].astype(np.float64), quat[picks].astype(np.float64)
    out = []
    for passes in (pool, NumpyShownPool(pool)):

        def run(passes: Any = passes) -> None:
            p, r, _ = passes.upper_body(wp, rot, tp, tq, None, 0.75)
            passes.hinge(p, r, KNEE_LIMBS)
            passes.hinge(p, r, ELBOW_LIMBS)

        run()
        t0 = time.perf_counter()
        for _ in range(repeats):
            run()
        out.append((time.perf_counter() - t0) / repeats * 1000.0)
    return out[0], out[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--players", default="1,10,25,50,100")
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--ticks", type=int, default=300, help="measured ticks per engine")
    ap.add_argument("--warmup", type=int, default=50)
    args = ap.parse_args(argv)
    counts = [int(x) for x in args.players.split(",")]
    cfg = EngineConfig(samples=args.samples)
    pos, quat = bench_frames()
    print(f"N = {args.samples}, {args.threads} threads, 4-point players, the generated walk")
    print(f"{'players':>7s} {'C p50':>8s} {'C p90':>8s} {'numpy p50':>10s} {'numpy p90':>10s}"
          f" {'numpy / C (p50)':>16s}")  # fmt: skip
    for P in counts:
        engines = []
        for _ in range(2):
            engine = load_engine(cfg, None, args.threads, Layout.HMD3_WAIST, "native", capacity=P)
            for p in range(P):
                engine.add_player(f"p{p}", seed=p)
            engines.append(engine)
        engines[1].pool = NumpyShownPool(engines[1].pool)
        times: list[list[float]] = [[], []]
        worst = 0.0
        for t in range(args.warmup + args.ticks):
            shown = []
            for engine, kept in zip(engines, times, strict=True):
                for p in range(P):
                    k = (t + 37 * p) % len(pos)
                    engine.push(f"p{p}", TrackerFrame(t, pos[k], quat[k]))
                t0 = time.perf_counter()
                result = engine.tick()
                if t >= args.warmup:
                    kept.append((time.perf_counter() - t0) * 1000.0)
                shown.append(result.poses)
            for a, b in zip(*shown, strict=True):
                worst = max(worst, float(np.abs(a.positions - b.positions).max()))
        c50, c90 = np.percentile(times[0], [50, 90])
        n50, n90 = np.percentile(times[1], [50, 90])
        print(f"{P:7d} {c50:8.2f} {c90:8.2f} {n50:10.2f} {n90:10.2f} {n50 / c50:15.2f}x")
        if worst > 1e-4:
            raise SystemExit(f"the two engines' poses differ by {worst:.2e} m")
    pool = load_engine(cfg, None, 1, Layout.HMD3_WAIST, "native").pool
    print("the passes alone (upper body, knees, elbows), ms a call")
    for E in counts:
        c, n = _passes_alone(pool, E)
        print(f"{E:7d} poses: C {c:.3f}, numpy {n:.3f} ({n / c:.0f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
