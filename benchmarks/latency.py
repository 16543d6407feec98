"""Latency benchmark: ``python benchmarks/latency.py [--players 16] [--room-size 8]
[--seconds 10] [--sdk python|typescript] [--lossy] [--json OUT]``.

Same as ``posecast bench latency``: SDK players (Python, or TypeScript in Node) on
loopback against a real ``posecast serve``, 60 Hz frames of a generated walk, every
room-mate's pose shown through the SDK's interpolator at 90 Hz; capture to first
display, p50 and p99, split into look-ahead, server queue and tick, transport and
client buffer, and with ``--lossy`` again behind the reliability suite's lossy relay
(``docs/latency-benchmark.md``).
"""

from __future__ import annotations

import sys

from posecast.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["bench", "latency", *sys.argv[1:]]))
