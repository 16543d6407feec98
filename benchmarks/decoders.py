"""Decoders side by side: ``python benchmarks/decoders.py --players 50 [--layout hmd3]
shipped@avx512f shipped@avx512bf16 DIR@avx512f shipped@avx2:bf16 ...``.

One engine per ``MODELS[@LEVEL[:PRECISION]]`` (``shipped``: the models in the package;
``DIR``: a models directory such as ``posecast export --out DIR`` writes; ``LEVEL``: the
native kernels' instruction-set level that engine ticks on, in its default precision,
bf16 on ``avx512bf16`` and fp32 on the others, or ``PRECISION`` (``fp32``, ``bf16``);
without a level, the level and precision the import chose), all in one process on the
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
from posecast.online.inference.native import (
    PRECISIONS,
    native_isa,
    native_isas,
    native_precision,
    set_native_isa,
    set_native_precision,
)
from posecast.tracking.layouts import Layout


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "engines", nargs="+", help="MODELS[@LEVEL[:PRECISION]]: shipped or a models directory"
    )
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
    # the level and precision the import chose: for engines that name no level
    default = native_isa(), native_precision().removesuffix("-emulated")
    specs: list[tuple[str, str, str]] = []
    for text in args.engines:
        models, _, at = text.partition("@")
        level, _, precision = at.partition(":")
        if level and level not in native_isas():
            ap.error(f"{text}: this CPU runs the levels {', '.join(native_isas())}")
        if precision and precision not in PRECISIONS:
            ap.error(f"{text}: the precision is one of {', '.join(PRECISIONS)}")
        if not level:
            level, precision = default
        precision = precision or ("bf16" if level == "avx512bf16" else "fp32")
        specs.append((models, level, precision))
    engines = []
    for models, level, precision in specs:
        set_native_isa(level)
        set_native_precision(precision)
        path = None if models == "shipped" else str(Path(models))
        engine = load_engine(cfg, path, args.threads, layout, "native", capacity=args.players)
        for p in range(args.players):
            engine.add_player(f"p{p}", seed=p)
        engines.append(engine)
    pos, quat = bench_frames()
    times: list[list[float]] = [[] for _ in engines]
    for t in range(args.warmup + args.ticks):
        for (_, level, precision), engine, kept in zip(specs, engines, times, strict=True):
            for p in range(args.players):
                k = (t + 37 * p) % len(pos)
                engine.push(f"p{p}", TrackerFrame(t, pos[k], quat[k]))
            set_native_isa(level)
            set_native_precision(precision)
            t0 = time.perf_counter()
            engine.tick()
            if t >= args.warmup:
                kept.append((time.perf_counter() - t0) * 1000.0)
    first = float(np.median(times[0]))
    print(f"{args.players} players, N = {args.samples}, {args.threads} threads, layout {layout}")
    print(f"{'engine':48s} {'p50 ms':>8s} {'p90 ms':>8s} {'p50 / first':>12s}  precision")
    for text, kept, (_, level, precision) in zip(args.engines, times, specs, strict=True):
        p50, p90 = np.percentile(kept, [50, 90])
        shown = precision if precision == "fp32" or level == "avx512bf16" else "bf16-emulated"
        print(f"{text:48s} {p50:8.2f} {p90:8.2f} {p50 / first:11.2f}x  {shown}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
