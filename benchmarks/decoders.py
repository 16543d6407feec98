"""Decoders side by side: ``python benchmarks/decoders.py --players 50 [--layout hmd3]
shipped@avx512f shipped@avx512bf16 DIR@avx512f ...``.

One engine per ``MODELS[@LEVEL]`` (``shipped``: the models in the package; ``DIR``: a
models directory such as ``posecast export --out DIR`` writes; ``LEVEL``: the native
kernels' instruction-set level that engine ticks on; without it, the level the
import chose), all in one process on the
``native`` backend, ticked in turn: every tick, each engine's players push the same
walking frames, then it ticks, timed alone. Interleaving puts the machine's drift and
the VM's jitter on every engine alike, so the ratios to the first are what to read.
Prints p50 and p90 per engine and each p50 over the first's.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from posecast.offline.evaluation.engine_speed import bench_frames
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine
from posecast.online.inference.native import native_isa, native_isas, set_native_isa
from posecast.tracking.layouts import Layout


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("engines", nargs="+", help="MODELS[@LEVEL]: shipped or a models directory")
    ap.add_argument("--players", type=int, default=50)
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--ticks", type=int, default=350, help="measured ticks per engine")
    ap.add_argument("--warmup", type=int, default=70)
    ap.add_argument("--layout", default=Layout.HMD3_WAIST.value, choices=[x.value for x in Layout])
    args = ap.parse_args(argv)
    layout = Layout(args.layout)
    if layout is Layout.SITES:
        ap.error("--layout sites: use `posecast bench engine --sets`")
    cfg = EngineConfig(samples=args.samples)
    default = native_isa()  # the level the import chose: for engines that name none
    specs: list[tuple[str, str]] = []
    for text in args.engines:
        models, _, level = text.partition("@")
        if level and level not in native_isas():
            ap.error(f"{text}: this CPU runs the levels {', '.join(native_isas())}")
        specs.append((models, level or default))
    engines = []
    for models, level in specs:
        set_native_isa(level)
        path = None if models == "shipped" else str(Path(models))
        engine = load_engine(cfg, path, args.threads, layout, "native", capacity=args.players)
        for p in range(args.players):
            engine.add_player(f"p{p}", seed=p)
        engines.append(engine)
    pos, quat = bench_frames()
    times: list[list[float]] = [[] for _ in engines]
    for t in range(args.warmup + args.ticks):
        for (_, level), engine, kept in zip(specs, engines, times, strict=True):
            for p in range(args.players):
                k = (t + 37 * p) % len(pos)
                engine.push(f"p{p}", TrackerFrame(t, pos[k], quat[k]))
            set_native_isa(level)
            t0 = time.perf_counter()
            engine.tick()
            if t >= args.warmup:
                kept.append((time.perf_counter() - t0) * 1000.0)
    first = float(np.median(times[0]))
    print(f"{args.players} players, N = {args.samples}, {args.threads} threads, layout {layout}")
    print(f"{'engine':48s} {'p50 ms':>8s} {'p90 ms':>8s} {'p50 / first':>12s}")
    for text, kept in zip(args.engines, times, strict=True):
        p50, p90 = np.percentile(kept, [50, 90])
        print(f"{text:48s} {p50:8.2f} {p90:8.2f} {p50 / first:11.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
