r"""What ``load.py`` drives and reads: the processes and the measurements.

A ``posecast serve`` subprocess (:func:`serve`, :class:`Server`: a
:class:`posecast.testing.serve.ServeProcess`: ``/metrics``, RSS, FDs, CPU), the
clients: ``posecast-sim`` subprocesses (:class:`Sim`: progress lines, the final JSON
summary, CPU) or the one lean generator (:class:`LeanClients`, driving
``lean_clients.py``), and the arithmetic of one measured window between two
:class:`Snapshot`\ s (:func:`window`: tick quantiles from histogram deltas, overruns,
CPU shares, poses received against what full rooms would get; :func:`lean_window`:
the lean generator's exact per-player delivery and its own CPU share).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from posecast.testing.serve import Metrics, ServeProcess, cpu_seconds, metric_sum, series_name

SECRET = "load-secret-" + "x" * 24
TICK_HZ = 60.0
DEADLINE_LE = "0.0167"  # the tick histogram's bucket edge at one 60 Hz period
LIMIT_SHARE = 0.01  # ticks over the deadline, and overruns, per window
MIN_TICK_HZ = 59.0
MIN_DELIVERY = 0.99  # lean clients: poses received / expected, per window
REPO = Path(__file__).resolve().parents[1]
_LABEL = re.compile(r'(\w+)="((?:[^"\\]|\\.)*)"')
_UNESCAPE = re.compile(r"\\(.)")


def _unescaped(m: re.Match[str]) -> str:
    return "\n" if m[1] == "n" else m[1]


LEAN_CLIENTS = Path(__file__).resolve().with_name("lean_clients.py")


# --- the processes -------------------------------------------------------------------------


def _machine_busy_s() -> tuple[float, float]:
    """(busy, total) CPU seconds of the whole machine so far, over all cores."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + values[4]  # idle + iowait
    total = sum(values[:8])  # guest time is already in user
    tick = os.sysconf("SC_CLK_TCK")
    return (total - idle) / tick, total / tick


class Server(ServeProcess):
    """The server under load: a :class:`~posecast.testing.serve.ServeProcess` logging
    to ``log``, plus what ``load.py`` reads of it."""

    def __init__(self, samples: int, log: Path, extra: list[str], cpus: set[int] | None) -> None:
        log.unlink(missing_ok=True)  # this run's lines only
        super().__init__(
            "--conn-per-ip-per-min", "1000000", "--sockets-per-ip", "1000000", *extra,
            secret=SECRET, samples=samples, lookahead=None, log=log,
            preexec_fn=confined(cpus),
        )  # fmt: skip

    def get(self, path: str, timeout_s: float = 5.0) -> str:
        """The body of ``GET path``; an error status raises."""
        status, body = self.http(path, timeout_s)
        if status != 200:
            raise RuntimeError(f"{path} answered {status}")
        return body

    def log_problems(self) -> list[str]:
        """The server's log lines at WARNING and above (it runs at --log-level WARNING)."""
        assert self.log is not None
        lines = self.log.read_text(errors="replace").splitlines()
        return [x for x in lines if x.strip()]


def confined(cpus: set[int] | None, nice: int = 0) -> Callable[[], None] | None:
    """A ``preexec_fn`` that confines the child to ``cpus`` (None: anywhere) and lowers
    its priority by ``nice``."""
    if not cpus and not nice:
        return None

    def apply() -> None:
        if cpus:
            os.sched_setaffinity(0, cpus)
        if nice:
            os.nice(nice)

    return apply


def parse_cpus(text: str) -> set[int]:
    """``"0"`` or ``"1,2"`` -> the CPU numbers."""
    return {int(x) for x in text.split(",") if x.strip()}


@contextmanager
def serve(
    samples: int, workdir: Path, extra: list[str] | None = None, cpus: set[int] | None = None
) -> Iterator[Server]:
    """``python -m posecast serve`` on a free port, ready; stopped (SIGTERM) on the way out."""
    with Server(samples, workdir / "server.log", extra or [], cpus) as server:
        server.wait_ready(timeout_s=30)
        yield server


@dataclass
class Sim:
    """One ``posecast-sim`` process (the SDK's simulator CLI), stopped with SIGINT."""

    proc: subprocess.Popen[bytes]
    players: int
    rooms: int
    out: Path
    report: Path
    summary: dict[str, Any] | None = None
    cpu_at_exit_s: float = 0.0

    @classmethod
    def start(
        cls,
        server: Server,
        workdir: Path,
        name: str,
        players: int,
        room_size: int,
        seconds: float,
        *,
        churn_every_s: float = 0.0,
        progress_every_s: float = 1.0,
        seed: int = 0,
        cpus: set[int] | None = None,
        nice: int = 0,
    ) -> Sim:
        rooms = math.ceil(players / room_size)
        out, report = workdir / f"{name}.out", workdir / f"{name}.json"
        cmd = [
            sys.executable,
            "-m",
            "posecast_client.cli.sim",
            "--url",
            f"ws://127.0.0.1:{server.port}/",
            "--secret",
            SECRET,
            "--players",
            str(players),
            "--rooms",
            str(rooms),
            "--room-prefix",
            name,
            "--duration",
            str(seconds),
            "--seed",
            str(seed),
            "-q",
            "--progress-every",
            str(progress_every_s),
            "--json",
            str(report),
        ]
        if churn_every_s > 0:
            cmd += ["--churn-every", str(churn_every_s)]
        with out.open("wb") as stdout:
            proc = subprocess.Popen(
                cmd, stdout=stdout, stderr=subprocess.STDOUT, preexec_fn=confined(cpus, nice)
            )
        return cls(proc, players, rooms, out, report)

    def cpu_s(self) -> float:
        if self.proc.poll() is not None:
            return self.cpu_at_exit_s
        with contextlib.suppress(FileNotFoundError, ProcessLookupError):  # exited just now
            self.cpu_at_exit_s = cpu_seconds(self.proc.pid)
        return self.cpu_at_exit_s

    def progress(self) -> dict[str, Any]:
        """Its latest progress line (poses so far, players joined, losses...)."""
        last: dict[str, Any] = {}
        for line in self.out.read_text(errors="replace").splitlines():
            if line.startswith("posecast-sim progress "):
                last = json.loads(line.split(" ", 2)[2])
        return last

    def stop(self, timeout_s: float = 60.0) -> dict[str, Any]:
        if self.proc.poll() is None:
            self.cpu_s()
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.report.exists():
            self.summary = json.loads(self.report.read_text())
        else:
            tail = self.out.read_text(errors="replace")[-2000:]
            self.summary = {"failed": {"process": f"exit {self.proc.returncode}: {tail}"}}
        return self.summary


@dataclass
class LeanClients:
    """The lean generator (``lean_clients.py``): one process for every player of a
    ramp, driven one JSON line each way over its stdin and stdout."""

    proc: subprocess.Popen[bytes]
    log: Path
    cpu_at_exit_s: float = 0.0

    @classmethod
    def start(
        cls,
        server: Server,
        workdir: Path,
        room_size: int,
        *,
        protocol: int = 2,
        cpus: set[int] | None = None,
        nice: int = 0,
    ) -> LeanClients:
        log = workdir / "lean.log"
        cmd = [sys.executable, str(LEAN_CLIENTS), "--url", server.url, "--secret", SECRET,
               "--room-size", str(room_size), "--protocol", str(protocol)]  # fmt: skip
        with log.open("wb") as err:
            proc = subprocess.Popen(
                cmd,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                preexec_fn=confined(cpus, nice),
            )
        lean = cls(proc, log)
        lean._read(60.0)  # {"ready": true}, once the walks are built
        return lean

    def _read(self, timeout_s: float) -> dict[str, Any]:
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout_s)
        line = self.proc.stdout.readline() if ready else b""
        if not line:
            tail = self.log.read_text(errors="replace")[-2000:]
            raise RuntimeError(f"lean_clients.py did not answer (exit {self.proc.poll()}): {tail}")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def ask(self, cmd: dict[str, Any], timeout_s: float = 30.0) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd).encode() + b"\n")
        self.proc.stdin.flush()
        return self._read(timeout_s)

    def add(self, players: int, timeout_s: float) -> dict[str, Any]:
        """``players`` more players join; returns once all are in (or failed)."""
        cmd = {"cmd": "add", "players": players, "timeout_s": timeout_s}
        return self.ask(cmd, timeout_s + 10.0 + 0.02 * players)

    def stats(self) -> dict[str, Any]:
        """The generator's counters now (``lean_clients.Generator.stats``)."""
        return self.ask({"cmd": "stats"})

    def cpu_s(self) -> float:
        if self.proc.poll() is None:
            with contextlib.suppress(FileNotFoundError, ProcessLookupError):
                self.cpu_at_exit_s = cpu_seconds(self.proc.pid)
        return self.cpu_at_exit_s

    def stop(self, timeout_s: float = 60.0) -> dict[str, Any]:
        """Every player closes; the final ``stats`` (``failed`` when it did not answer)."""
        final: dict[str, Any]
        try:
            self.cpu_s()
            final = self.ask({"cmd": "stop"}, timeout_s)
        except (OSError, RuntimeError) as exc:
            final = {"failed": {"process": repr(exc)}}
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                pipe.close()
        return final


# --- windows -------------------------------------------------------------------------------


@dataclass
class Snapshot:
    t: float
    metrics: Metrics
    server_cpu_s: float
    client_cpu_s: float
    machine_busy_s: float
    machine_total_s: float
    poses: int  # received by the clients so far
    lean: dict[str, Any] | None = None  # the lean generator's stats, when it is the client

    @classmethod
    def take(cls, server: Server, sims: list[Sim], lean: LeanClients | None = None) -> Snapshot:
        busy, total = _machine_busy_s()
        t, metrics, server_cpu = time.monotonic(), server.metrics(), server.cpu_seconds()
        if lean is not None:
            stats = lean.stats()
            client_cpu, poses = lean.cpu_s(), sum(int(row[2]) for row in stats["players"])
        else:
            stats, client_cpu = None, sum(s.cpu_s() for s in sims)
            poses = sum(int(s.progress().get("poses", 0)) for s in sims)
        return cls(t, metrics, server_cpu, client_cpu, busy, total, poses, stats)


def _bucket_counts(m: Metrics, name: str) -> list[tuple[float, float]]:
    prefix = name + '_bucket{le="'
    out = [(float(k[len(prefix) : -2]), v) for k, v in m.items() if k.startswith(prefix)]
    return sorted(out)


def hist_quantile(q: float, buckets: list[tuple[float, float]]) -> float:
    """Prometheus' histogram_quantile: linear within the bucket that holds rank q*n."""
    n = buckets[-1][1]
    if n <= 0:
        return math.nan
    rank, lower, below = q * n, 0.0, 0.0
    for upper, cum in buckets:
        if cum >= rank:
            if math.isinf(upper):
                return lower  # beyond the last finite edge: report that edge
            inside = cum - below
            return lower + (upper - lower) * ((rank - below) / inside if inside else 1.0)
        lower, below = upper, cum
    return lower  # pragma: no cover - the +Inf bucket always holds n


def by_worker(m: Metrics) -> dict[str, Metrics]:
    """A scrape split by its ``worker`` label (``posecast serve --workers N``), each
    part's series keyed without it; one part, ``""``, for a single process."""
    out: dict[str, Metrics] = {}
    for key, value in m.items():
        name, _, inner = key.partition("{")
        labels = dict(_LABEL.findall(inner))
        worker = labels.pop("worker", "")
        if worker != "supervisor":
            plain = {k: _UNESCAPE.sub(_unescaped, v) for k, v in labels.items()}
            out.setdefault(worker, {})[series_name(name, plain)] = value
    return out


def _ticks(a: Metrics, b: Metrics, seconds: float) -> dict[str, Any]:
    """One process's tick figures between two scrapes."""
    ta = _bucket_counts(a, "posecast_tick_seconds")
    tb = _bucket_counts(b, "posecast_tick_seconds")
    if len(ta) != len(tb):  # a worker (re)started within the window: from zero
        ta = [(le, 0.0) for le, _ in tb]
    diff = [(le, cb - ca) for (le, ca), (_, cb) in zip(ta, tb, strict=True)]
    ticks = diff[-1][1]
    in_time = dict(zip((f"{le:g}" for le, _ in diff), (c for _, c in diff), strict=True))[
        f"{float(DEADLINE_LE):g}"
    ]
    tick_sum = b.get("posecast_tick_seconds_sum", 0.0) - a.get("posecast_tick_seconds_sum", 0.0)
    overruns = b.get("posecast_tick_overruns_total", 0.0) - a.get(
        "posecast_tick_overruns_total", 0.0
    )
    return {
        "ticks": int(ticks),
        "tick_hz": round(ticks / seconds, 2),
        "tick_ms_mean": round(1000 * tick_sum / ticks, 2) if ticks else None,
        "tick_ms_p50": round(1000 * hist_quantile(0.5, diff), 2),
        "tick_ms_p99": round(1000 * hist_quantile(0.99, diff), 2),
        "ticks_over_16_7ms": round(1 - in_time / ticks, 4) if ticks else None,
        "overruns": int(overruns),
        "overrun_share": round(overruns / ticks, 4) if ticks else None,
    }


def window(a: Snapshot, b: Snapshot, full_rooms_poses_per_s: float) -> dict[str, Any]:
    """What happened between two snapshots: tick figures, CPU, poses. With several
    workers the tick figures are the worst worker's (highest p99, largest shares,
    lowest rate), and ``workers`` holds each one's."""
    seconds = b.t - a.t
    wa, wb = by_worker(a.metrics), by_worker(b.metrics)
    each = {w: _ticks(wa.get(w, {}), m, seconds) for w, m in sorted(wb.items())}
    worst = max(each.values(), key=lambda t: (t["ticks_over_16_7ms"] or 0, t["tick_ms_p99"]))
    ticks_fig = dict(worst)
    if len(each) > 1:
        ticks_fig["tick_hz"] = min(t["tick_hz"] for t in each.values())
        ticks_fig["overrun_share"] = max(t["overrun_share"] or 0 for t in each.values())
        ticks_fig["tick_ms_p99"] = max(t["tick_ms_p99"] for t in each.values())

    def d(series: str) -> float:
        return metric_sum(b.metrics, series) - metric_sum(a.metrics, series)

    machine = (b.machine_busy_s - a.machine_busy_s) / seconds
    server_cpu = (b.server_cpu_s - a.server_cpu_s) / seconds
    client_cpu = (b.client_cpu_s - a.client_cpu_s) / seconds
    poses_per_s = (b.poses - a.poses) / seconds
    return {
        "seconds": round(seconds, 2),
        **ticks_fig,
        "workers": {w: {**t, "players": players_in(wb[w])} for w, t in each.items()}
        if len(each) > 1
        else None,
        "server_cpu_cores": round(server_cpu, 3),
        "client_cpu_cores": round(client_cpu, 3),
        "other_cpu_cores": round(max(0.0, machine - server_cpu - client_cpu), 3),
        "poses_received_per_s": round(poses_per_s, 1),
        "delivery": round(poses_per_s / full, 4) if (full := full_rooms_poses_per_s) else None,
        "frames_per_s": round(d("posecast_frames_total") / seconds, 1),
        "poses_superseded_per_s": round(d("posecast_poses_superseded_total") / seconds, 1),
    }


def lean_window(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Delivery and the generator's own CPU between two ``stats`` of the lean generator.

    The server sends each of a room's poses to every member, the sender included, once
    per tick, so a player in a room of ``m`` members (itself included) at the room's pose
    rate ``r`` (``welcome.rate_hz``, 60) should receive ``r * m * dt`` poses in ``dt``
    seconds (v1 ``pose`` messages; v2 records, ``m`` of them in each tick's ``poses``;
    ``dt`` on the generator's clock, read with the counts). ``delivery`` is
    what all players received over what they all should have; ``delivery_worst`` the
    lowest player's share. Players that joined within the window are left out.
    """
    dt = b["t"] - a["t"]
    before = {row[0]: row for row in a["players"]}
    got = want = 0.0
    worst = math.inf
    for player, _room, poses, members, rate_hz, _open in b["players"]:
        if player not in before:
            continue
        expected = rate_hz * members * dt
        received = poses - before[player][2]
        got, want = got + received, want + expected
        worst = min(worst, received / expected if expected else 0.0)
    ticks = b["ticks"] - a["ticks"]
    return {
        "expected_poses_per_s": round(want / dt, 1),
        "delivery": round(got / want, 4) if want else None,
        "delivery_worst": round(worst, 4) if want else None,
        "generator_cpu_cores": round((b["cpu_s"] - a["cpu_s"]) / dt, 3),
        "generator_frames_per_s": round((b["frames_sent"] - a["frames_sent"]) / dt, 1),
        "generator_late_ticks": b["late_ticks"] - a["late_ticks"],
        "generator_ticks": ticks,
        "client_errors": b["errors"] - a["errors"],
    }


def sustainable(w: dict[str, Any], min_delivery: float | None = None) -> bool:
    """The tick criteria; with ``min_delivery``, poses delivered too (lean clients)."""
    return bool(
        w["ticks"]
        and w["ticks_over_16_7ms"] <= LIMIT_SHARE
        and w["overrun_share"] <= LIMIT_SHARE
        and w["tick_hz"] >= MIN_TICK_HZ
        and (min_delivery is None or (w["delivery"] or 0.0) >= min_delivery)
    )


def criteria(min_delivery: float | None = None) -> str:
    delivered = "" if min_delivery is None else f"poses delivered >= {min_delivery:.0%}, "
    return (
        f"per window: ticks over 16.7 ms <= {LIMIT_SHARE:.0%} (tick p99 <= 16.7 ms), "
        f"overruns <= {LIMIT_SHARE:.0%} of ticks, tick rate >= {MIN_TICK_HZ:g} Hz, "
        f"{delivered}all players joined, no connection lost"
    )


def expected_poses_per_s(sims: list[Sim]) -> float:
    """Every player receives every room-mate's pose (its own too) at 60 Hz."""
    total = 0.0
    for s in sims:
        sizes = [len(range(r, s.players, s.rooms)) for r in range(s.rooms)]
        total += TICK_HZ * sum(n * n for n in sizes)
    return total


def players_in(m: Metrics) -> int:
    return int(metric_sum(m, "posecast_players"))


def wait_players(server: Server, n: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if players_in(server.metrics()) >= n:
            return True
        time.sleep(0.25)
    return False


def losses(sims: list[Sim]) -> int:
    return sum(int(s.progress().get("connection_losses", 0)) for s in sims)


def version() -> dict[str, Any]:
    """Which code was measured: the commit and whether the server's tree differs."""

    def git(*a: str) -> str:
        done = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True)
        return done.stdout.strip()

    import posecast

    return {
        "commit": git("rev-parse", "--short", "HEAD"),
        "server_tree_modified": bool(git("status", "--porcelain", "server")),
        "server_package": str(Path(posecast.__file__).parent),
    }
