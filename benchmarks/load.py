"""Load and soak: simulated players against a real ``posecast serve``.

    python benchmarks/load.py ramp --samples 100 --room-size 8 --step 4 --json ramp-n100.json
    python benchmarks/load.py ramp --clients sdk --samples 100 --step 4    # SDK clients
    python benchmarks/load.py soak --samples 10 --players 64 --seconds 600 \\
                                   --churn-every 3 --json soak.json

Both start the server as a subprocess (``python -m posecast serve --port 0``) on the
same machine as the clients, which share its cores: the clients' CPU is measured and
printed beside the server's, and the machine's other load (``other_cores``) too.
``--server-cpus``/``--client-cpus`` pin them apart, ``--client-nice`` lowers the
clients' priority.

The ramp's clients (``--clients``):

* ``lean`` (the default): every player in one ``lean_clients.py`` process (one
  asyncio loop on ``websockets``; frames pre-encoded once per player, 60 Hz, seq
  counting up; poses counted, never decoded), so that the load generator takes as
  little of the server's CPU as it can: about 0.008 of a core per player (0.15 at 20
  players), against 0.025 for SDK clients. ``--protocol 2`` (the default) speaks
  ``posecast.v2`` as the SDKs do (one ``poses`` message of pose records per tick, the
  records counted by walking their lengths); ``--protocol 1`` speaks ``posecast.v1``
  (a ``pose`` message per avatar per tick, counted from its first bytes). Rooms are filled in
  order across steps, so ``--room-size 8 --step 4`` really gives rooms of 8. It
  reports its own CPU (``process_time`` over wall time) and, per player, the poses
  received against the expected ``welcome.rate_hz x room members x seconds``.
* ``sdk``: one ``posecast-sim`` process per step (the SDK's simulator: each player a
  real SDK ``Client`` replaying the built-in procedural walk, receiving and decoding
  every room-mate's pose), in rooms of at most ``--room-size`` within that step's
  players (``--step 4`` gives rooms of 4). A Python SDK client costs about 0.02-0.03
  of a core per player, so on a small machine the clients take as much CPU as the
  server. The soak always uses these.

**ramp** adds ``--step`` players at a time, waits until they have joined and
``--settle`` seconds more, then measures a ``--window`` of seconds from the server's
``/metrics`` (differences of the counters over the window). A step is *sustainable*
when, over its window:

* at most 1 % of ticks took longer than 16.7 ms (one 60 Hz period): tick p99 <= 16.7 ms;
  the histogram has a bucket edge at 0.0167 s, so this is read exactly, not estimated;
* at most 1 % of ticks overran (started a whole period late, ``posecast_tick_overruns``);
* ticks ran at >= 59 per second;
* (lean clients) the players received >= 99 % of the poses expected
  (``load_rig.lean_window``);
* every player had joined and no client lost its connection.

The maximum sustainable players is the largest step such that it and every step
below it were sustainable. The ramp stops after two unsustainable steps in a row or
at ``--max-players``. Tick p50/p99 in the table are interpolated within the
histogram's buckets (..., 8, 12, 16.7, 25, 50 ms), as Prometheus' histogram_quantile
does, so they are coarse; the share of ticks over 16.7 ms is exact.

**soak** runs ``--players`` players for ``--seconds`` while one of them leaves (``bye``)
and a new player takes its place every ``--churn-every`` seconds (``posecast-sim
--churn-every``). Every ``--sample-every`` seconds it reads the server's resident
memory (``/proc/PID/status`` VmRSS), open file descriptors (``/proc/PID/fd``) and asyncio
tasks (``posecast_asyncio_tasks``); per ``--window`` it prints tick p50/p99, overruns,
CPU and the poses the clients received. Measured time starts once every player has
joined; the first ``--warmup`` seconds of it are warm-up (RSS "start" is the first
sample after it, RSS "end" the last sample before the clients stop). Checks:

* RSS grew by at most ``--max-rss-growth`` % (5) from start to end;
* FDs and tasks under load stayed within what the churn explains (one connection in
  transition: the largest value after warm-up at most ``--fd-slack`` / ``--task-slack``
  above the smallest), and came back to their idle values before the load, once the
  clients had gone;
* no unexplained disconnect: no client lost its connection or failed, no error
  message reached a client, and the server accepted exactly one connection per
  client session (a reconnect would add one). Expected disconnects are the churn's
  leaves plus the final leave of every player;
* poses flowed: in every window after warm-up the clients received at least
  ``--min-delivery`` (50 %) of the poses full rooms would get (60 Hz x room size per
  player; each churn costs the room the new player's first poses, which take
  ``first_pose_ms`` from connecting to arrive), and the server answered ``/healthz``
  at the end.

It prints its figures, writes them with ``--json``, and exits 1 when a check failed.
The ramp is in ``load_ramp.py``, the soak in ``load_soak.py``, what they print in
``load_report.py``; the processes and the window arithmetic are in ``load_rig.py``, the
lean generator in ``lean_clients.py``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from load_ramp import ramp
from load_report import print_ramp_summary, print_soak_summary
from load_rig import parse_cpus
from load_soak import soak

# --- command line --------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    for name in ("ramp", "soak"):
        p = sub.add_parser(name)
        p.add_argument("--samples", type=int, default=100, help="server --samples N (100)")
        p.add_argument("--room-size", type=int, default=4, help="players per room (4)")
        p.add_argument("--join-timeout", type=float, default=60.0, help="seconds to join (60)")
        p.add_argument(
            "--server-arg",
            action="append",
            default=[],
            help="one more argument for posecast serve (repeatable)",
        )
        p.add_argument(
            "--server-cpus", type=parse_cpus, help="pin the server to these CPUs, e.g. 0"
        )
        p.add_argument(
            "--client-cpus", type=parse_cpus, help="pin the clients to these CPUs, e.g. 1"
        )
        p.add_argument(
            "--client-nice", type=int, default=0,
            help="run the clients this much nicer than the server, so that they yield to it (0)",
        )  # fmt: skip
        p.add_argument("--json", type=Path, help="also write the figures here")
    r = sub.choices["ramp"]
    r.add_argument(
        "--clients", choices=("lean", "sdk"), default="lean",
        help="lean: every player in one lean_clients.py process (pre-encoded frames, poses "
        "counted, not decoded); sdk: a posecast-sim process of SDK clients per step (lean)",
    )  # fmt: skip
    r.add_argument(
        "--protocol", type=int, choices=(1, 2), default=2,
        help="lean clients' wire protocol: 2, posecast.v2 pose records (what the SDKs speak); "
        "1, posecast.v1, one pose message per avatar per tick (2)",
    )  # fmt: skip
    r.add_argument("--step", type=int, default=4, help="players added per step (4)")
    r.add_argument("--max-players", type=int, default=256, help="stop before passing this")
    r.add_argument("--settle", type=float, default=3.0, help="seconds after joining (3)")
    r.add_argument("--window", type=float, default=10.0, help="measured seconds per step (10)")
    s = sub.choices["soak"]
    s.add_argument("--players", type=int, default=64, help="players at once (64)")
    s.add_argument("--seconds", type=float, default=600.0, help="measured seconds (600)")
    s.add_argument("--warmup", type=float, default=60.0, help="of which warm-up (60)")
    s.add_argument("--churn-every", type=float, default=3.0, help="one leave+join per S s (3)")
    s.add_argument("--procs", type=int, default=2, help="posecast-sim processes (2)")
    s.add_argument("--window", type=float, default=30.0, help="seconds per printed window (30)")
    s.add_argument("--sample-every", type=float, default=5.0, help="RSS/FD/task sampling (5)")
    s.add_argument(
        "--min-delivery",
        type=float,
        default=0.5,
        help="poses received / a full room's, every window after warm-up (0.5)",
    )
    s.add_argument("--max-rss-growth", type=float, default=5.0, help="percent (5)")
    s.add_argument("--fd-slack", type=int, default=4, help="FD spread allowed under load (4)")
    s.add_argument("--task-slack", type=int, default=8, help="task spread under load (8)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="posecast-load-") as tmp:
        if args.mode == "ramp":
            report = ramp(args, Path(tmp))
            print_ramp_summary(report)
            ok = report["server_alive"]
        else:
            report = soak(args, Path(tmp))
            print_soak_summary(report)
            ok = report["ok"]
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n", encoding="utf-8")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
