"""``load.py ramp``: add players a step at a time until the server no longer sustains
60 Hz (the criteria and the clients are in ``load.py``'s docstring)."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

from load_report import pinning, print_ramp_row
from load_rig import (
    MIN_DELIVERY,
    LeanClients,
    Server,
    Sim,
    Snapshot,
    criteria,
    expected_poses_per_s,
    lean_window,
    losses,
    players_in,
    serve,
    sustainable,
    version,
    wait_players,
    window,
)


class RampLoad:
    """The ramp's clients: ``add`` players, take a :class:`Snapshot`, read a window."""

    def __init__(self, args: argparse.Namespace, server: Server, workdir: Path) -> None:
        self.args, self.server, self.workdir = args, server, workdir
        self.players = 0
        self.sims: list[Sim] = []
        self.lean: LeanClients | None = None
        if args.clients == "lean":
            cpus, nice = args.client_cpus, args.client_nice
            self.lean = LeanClients.start(
                server, workdir, args.room_size, protocol=args.protocol, cpus=cpus, nice=nice
            )

    def add(self, n: int) -> bool:
        """``n`` more players; whether every player has joined (the server's count)."""
        self.players += n
        if self.lean is not None:
            self.lean.add(n, self.args.join_timeout)
        else:
            step = len(self.sims)
            self.sims.append(
                Sim.start(
                    self.server, self.workdir, f"ramp{step}", n, self.args.room_size, 3600.0,
                    seed=1000 * step, cpus=self.args.client_cpus, nice=self.args.client_nice,
                )
            )  # fmt: skip
        return wait_players(self.server, self.players, self.args.join_timeout)

    def snapshot(self) -> Snapshot:
        return Snapshot.take(self.server, self.sims, self.lean)

    def window(self, a: Snapshot, b: Snapshot) -> dict[str, Any]:
        if self.lean is None:
            row = window(a, b, expected_poses_per_s(self.sims))
            row["connection_losses"] = losses(self.sims)
            return row
        assert a.lean is not None and b.lean is not None
        lean = lean_window(a.lean, b.lean)
        row = window(a, b, lean["expected_poses_per_s"])
        row.update(lean)  # its delivery is per player, on the generator's own clock
        row["connection_losses"] = b.lean["connection_losses"]
        return row

    def stop(self) -> list[dict[str, Any]]:
        if self.lean is not None:
            return [self.lean.stop()]
        return [s.stop() for s in self.sims]


def ramp(args: argparse.Namespace, workdir: Path) -> dict[str, Any]:
    rows: list[dict[str, Any]] = []
    failing = 0
    min_delivery = MIN_DELIVERY if args.clients == "lean" else None
    clients = f"lean, posecast.v{args.protocol}" if args.clients == "lean" else args.clients
    print(f"ramp: N={args.samples}, rooms of {args.room_size}, +{args.step} players a step, "
          f"clients {clients}", flush=True)  # fmt: skip
    with serve(args.samples, workdir, args.server_arg, args.server_cpus) as server:
        load = RampLoad(args, server, workdir)
        try:
            while True:
                joined = load.add(args.step)
                time.sleep(args.settle)
                a = load.snapshot()
                time.sleep(args.window)
                b = load.snapshot()
                row = {
                    "players": load.players,
                    "joined": players_in(b.metrics),
                    **load.window(a, b),
                }
                row["client_cpu_per_player"] = round(row["client_cpu_cores"] / load.players, 4)
                row["sustainable"] = (
                    joined and row["connection_losses"] == 0 and sustainable(row, min_delivery)
                )
                rows.append(row)
                print_ramp_row(row, header=len(rows) == 1)
                if row.get("workers"):
                    print("        workers: " + "; ".join(
                        f"{w}: {t['players']} players, tick p99 {t['tick_ms_p99']:.1f} ms, "
                        f"{t['ticks_over_16_7ms']:.1%} over"
                        for w, t in row["workers"].items()), flush=True)  # fmt: skip
                if row.get("generator_late_ticks"):
                    print(
                        f"        the lean generator sent {row['generator_late_ticks']} of its "
                        f"{row['generator_ticks']} ticks a period late: the clients fell behind",
                        flush=True,
                    )
                failing = 0 if row["sustainable"] else failing + 1
                if failing >= 2 or load.players + args.step > args.max_players:
                    break
        finally:
            summaries = load.stop()
        alive = server.alive()
    best = 0
    for row in rows:
        if not row["sustainable"]:
            break
        best = row["players"]
    return {
        "mode": "ramp",
        "clients": args.clients,
        "protocol": args.protocol if args.clients == "lean" else None,
        "samples": args.samples,
        "room_size": args.room_size,
        "step": args.step,
        "window_s": args.window,
        "machine_cores": os.cpu_count(),
        "pinning": pinning(args),
        "criteria": criteria(min_delivery),
        "rows": rows,
        "max_sustainable_players": best,
        "server_alive": alive,
        "client_failures": sum(len(s.get("failed", {})) for s in summaries),
        "version": version(),
    }
