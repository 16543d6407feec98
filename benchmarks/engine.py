"""Engine benchmark: ``python benchmarks/engine.py [--players 1,10,50,100,200]
[--backend native,onnx] [--json OUT]``.

Same as ``posecast bench engine``; prints per-tick p50/p99 per backend (several
backends are measured side by side, count by count, with a speed-up table), the
largest player count that holds 60 Hz (p99 under 16.7 ms), achieved GFLOP/s, the
native kernels' level, resident memory per player, and the batched engine against a
naive per-player loop.
"""

from __future__ import annotations

import sys

from posecast.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["bench", "engine", *sys.argv[1:]]))
