"""The display clock against ``to_server`` for rendering: ``python benchmarks/clock_display.py
[--minutes 10] [--seeds 5] [--max-delay-ms 40,5] [--json out.json]``.

A simulated client on the Python SDK's ``ClockSync`` (``posecast_client.clock``), with no
sockets: the server's clock is the client's plus a constant offset (``--drift-ppm`` adds
a rate error), each one-way delay is uniform in ``[0, max_delay]``, drawn apart for the
way out and back, and the server holds each ping 0.2 ms. Pings go as the SDKs send
them: four 50 ms apart at the start (the burst after a join), then one every 2 s; a pong
is added at its arrival time ``t3``. Frames come at 90 Hz from 0.5 s on; each renders at
``to_server(t)`` (the estimate) and at ``display_time(t)`` (the display clock, on a
second ``ClockSync`` fed the same exchanges).

For each, over every frame after the first rendered one: the largest deviation of a
frame's rendered time step from the true 1/90 s (an avatar moving at v pops by v times
it), the largest ``|rendered - true server time|`` (also from 20 s on, once the burst's
pongs have left the window, and its mean), and how many frames stepped more than 1 ms
off 1/90 s. The figures are the worst (the mean: over all frames) of ``--seeds`` runs.
"""

from __future__ import annotations

import argparse
import json
import random
from dataclasses import dataclass
from typing import Any

from posecast_client.clock import ClockSync

OFFSET_S = 1234.5  # server minus client at client time 0
FPS = 90.0
HOLD_S = 0.0002
BURST = (0.0, 0.05, 0.10, 0.15)
PING_EVERY_S = 2.0
WARMUP_S = 20.0  # the window holds the burst's pongs until about 10 s


@dataclass
class Worst:
    step_dev_s: float = 0.0  # largest |rendered step - 1/90|
    error_s: float = 0.0  # largest |rendered - true server time|
    late_error_s: float = 0.0  # the same from WARMUP_S on (after the first pongs)
    error_sum_s: float = 0.0  # for the mean |rendered - true server time|
    popped: int = 0  # frames whose step is off by more than 1 ms
    frames: int = 0

    def merge(self, other: Worst) -> None:
        self.step_dev_s = max(self.step_dev_s, other.step_dev_s)
        self.error_s = max(self.error_s, other.error_s)
        self.late_error_s = max(self.late_error_s, other.late_error_s)
        self.error_sum_s += other.error_sum_s
        self.popped += other.popped
        self.frames += other.frames


def run(seed: int, minutes: float, max_delay_s: float, drift: float) -> dict[str, Worst]:
    rng = random.Random(seed)
    end = 60.0 * minutes

    def server(t: float) -> float:
        return t + OFFSET_S + drift * t

    pings = [*BURST]
    while pings[-1] + PING_EVERY_S <= end:
        pings.append(pings[-1] + PING_EVERY_S)
    pongs = []  # (t3, t0, t1, t2)
    for t0 in pings:
        up, down = rng.uniform(0, max_delay_s), rng.uniform(0, max_delay_s)
        t1 = server(t0 + up)
        t2 = t1 + HOLD_S
        pongs.append((t0 + up + HOLD_S + down, t0, t1, t2))
    pongs.sort()

    estimate, display = ClockSync(), ClockSync()
    worst = {"to_server": Worst(), "display_time": Worst()}
    last: dict[str, float] = {}
    k, i = 0, 0
    while (t := 0.5 + k / FPS) <= end:
        k += 1
        while i < len(pongs) and pongs[i][0] <= t:
            t3, t0, t1, t2 = pongs[i]
            estimate.add(t0, t1, t2, t3)
            display.add(t0, t1, t2, t3)
            i += 1
        if estimate.offset_s is None:
            continue
        true = server(t)
        for name, shown in (
            ("to_server", estimate.to_server(t)),
            ("display_time", display.display_time(t)),
        ):
            w = worst[name]
            err = abs(shown - true)
            w.error_s = max(w.error_s, err)
            if t >= WARMUP_S:
                w.late_error_s = max(w.late_error_s, err)
            if name in last:
                dev = abs((shown - last[name]) - (true - server(t - 1 / FPS)))
                w.step_dev_s = max(w.step_dev_s, dev)
                w.popped += dev > 0.001
                w.frames += 1
                w.error_sum_s += err
            last[name] = shown
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--max-delay-ms", default="40,5", help="one-way delay bounds to run, ms")
    ap.add_argument("--drift-ppm", type=float, default=0.0, help="server clock rate error")
    ap.add_argument("--json", help="also write the figures here")
    args = ap.parse_args()
    rows: list[dict[str, Any]] = []
    print(f"{args.minutes:g} min at {FPS:g} Hz, pings every {PING_EVERY_S:g} s, worst of "
          f"{args.seeds} seeds, drift {args.drift_ppm:g} ppm; errors in ms")  # fmt: skip
    print(f"{'one-way delay':>13} {'clock':>12} {'max step dev':>12} {'max |err|':>9} "
          f"{'after 20 s':>10} {'mean |err|':>10} {'frames >1 ms off':>17}")  # fmt: skip
    for bound in (float(x) for x in args.max_delay_ms.split(",")):
        total = {"to_server": Worst(), "display_time": Worst()}
        for seed in range(args.seeds):
            for name, w in run(seed, args.minutes, bound / 1000, args.drift_ppm * 1e-6).items():
                total[name].merge(w)
        for name, w in total.items():
            row = {
                "max_delay_ms": bound, "clock": name, "max_step_dev_ms": w.step_dev_s * 1e3,
                "max_error_ms": w.error_s * 1e3, "max_error_after_warmup_ms": w.late_error_s * 1e3,
                "mean_error_ms": w.error_sum_s / max(w.frames, 1) * 1e3,
                "frames_over_1ms": w.popped, "frames": w.frames,
            }  # fmt: skip
            rows.append(row)
            print(f"{f'U(0, {bound:g})':>13} {name:>12} {row['max_step_dev_ms']:12.3f} "
                  f"{row['max_error_ms']:9.3f} {row['max_error_after_warmup_ms']:10.3f} "
                  f"{row['mean_error_ms']:10.3f} {w.popped:>7} / {w.frames}")  # fmt: skip
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"args": vars(args), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
