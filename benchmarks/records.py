"""v2 delta records in C against numpy: ``python benchmarks/records.py
[--poses 1,8,48,100,336] [--ticks 300] [--json records.json]``.

A tick's deltas are encoded on the event loop's thread, in one
:func:`~posecast.online.protocol.records.encode_deltas` call with every distinct
(pose, client reference) pair of the tick: about one pair per player where the clients
of a room share their references, up to one per client and room-mate where they do not
(different pose rates, superseded slots). For each count of pairs ``M`` the two
encoders (``native``, ``pc_records.c``, what the server uses where it loads; ``numpy``,
the reference) encode the same tick in turn, tick after tick, in one process on a
smooth motion (each pose a step along its own sine path from the previous one, as a
player's is), so machine load hits both alike; prints each one's p50 and p90 per call,
microseconds per pose and the ratio, and checks that the two wrote the same bytes.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from posecast.online.protocol import records
from posecast.online.protocol.records import PoseState, Recon


def _motion(m: int, ticks: int) -> np.ndarray:
    """World rotations ``(ticks + 1, m, 19, 4)``: each joint turning along a sine path."""
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(m, 19, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(m, 19, 1))
    k = np.arange(ticks + 1)[:, None, None, None]
    items = records.rotvec2quat(axes * 0.3 * np.sin(k / 9.0 + phase))
    world = np.empty_like(items)
    for t in range(ticks + 1):
        for i in range(m):
            world[t, i] = records.items2world(items[t, i])
    return world


def _run(m: int, ticks: int) -> dict[str, float | int]:
    world = _motion(m, ticks)
    names = [f"p{i}" for i in range(m)]
    zero = np.zeros((m, 19, 3))
    first = PoseState.batch(names, [0] * m, 0.0, zero, world[0], [1.0] * m, [False] * m)
    start: list[Recon] = [s.keyframe()[1] for s in first if s is not None]
    refs = {enc: list(start) for enc in records.DELTA_ENCODERS}
    times: dict[str, list[float]] = {enc: [] for enc in records.DELTA_ENCODERS}
    same = total = 0
    for t in range(1, ticks + 1):
        roots = [(10 * t, 9500, 0)] * m
        got = {}
        for enc in records.DELTA_ENCODERS:
            r = refs[enc]
            t0 = time.perf_counter()
            out = records.encode_deltas(r, [t] * m, roots, world[t], [0] * m, encoder=enc)
            times[enc].append(time.perf_counter() - t0)
            refs[enc] = [old if o is None else o[1] for o, old in zip(out, r, strict=True)]
            got[enc] = [None if o is None else o[0] for o in out]
        if "native" in got:
            total += m
            same += sum(a == b for a, b in zip(got["native"], got["numpy"], strict=True))
    row: dict[str, float | int] = {"poses": m, "ticks": ticks}
    for enc, ts in times.items():
        row[f"{enc}_p50_ms"] = float(np.percentile(ts, 50) * 1e3)
        row[f"{enc}_p90_ms"] = float(np.percentile(ts, 90) * 1e3)
    if "native" in times:
        row["ratio_p50"] = row["numpy_p50_ms"] / row["native_p50_ms"]
        row["same_bytes"] = same / total
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", default="1,8,48,100,336", help="pairs per call, comma-separated")
    ap.add_argument("--ticks", type=int, default=300, help="calls per encoder and count")
    ap.add_argument("--json", help="also write the rows here")
    args = ap.parse_args()
    rows = [_run(int(m), args.ticks) for m in args.poses.split(",")]
    print(f"encoders: {', '.join(records.DELTA_ENCODERS)} (server: {records.DELTA_ENCODER})")
    print("poses  numpy p50/p90 ms  us/pose   native p50/p90 ms  us/pose   ratio  same bytes")
    for r in rows:
        m = int(r["poses"])
        line = f"{m:5d}  {r['numpy_p50_ms']:7.3f} {r['numpy_p90_ms']:7.3f}  "
        line += f"{r['numpy_p50_ms'] * 1e3 / m:7.1f}"
        if "native_p50_ms" in r:
            line += f"   {r['native_p50_ms']:7.3f} {r['native_p90_ms']:7.3f}  "
            line += f"{r['native_p50_ms'] * 1e3 / m:7.1f}   {r['ratio_p50']:5.1f}x"
            line += f"  {r['same_bytes'] * 100:6.2f} %"
        print(line)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
