"""The hostile-input tests' arena (``test_hostile_*.py``): a real ``posecast serve``
process plus healthy players in a process of their own (``healthy_players.py``). Two
players stream walk frames at 60 Hz in room ``r1``, two more in room ``r2``; the arena
counts the poses each receives of its partner, and reads the server's tick and pose
counters, so a test can compare the rates during an attack with a baseline window taken
just before. Also :func:`scrape`: ``/metrics`` parsed into ``{(name, labels): value}``."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from posecast.online.config import ServerConfig
from posecast.testing.serve import Series, ServeProcess, parse_series
from posecast.testing.serve import http_get as serve_http_get
from posecast.tracking.layouts import Layout
from tests.system.reliability.healthy_players import HEALTHY, WATCHED

REPO = Path(__file__).resolve().parents[3]

# --- metrics ----------------------------------------------------------------------------

Samples = dict[Series, float]  # {(name, sorted label pairs): value}


def http_get(
    port: int, path: str, source_ip: str = "127.0.0.1"
) -> tuple[int, dict[str, str], bytes]:
    """``GET path`` on the server's port: status, headers, body (no redirects)."""

    class _NoRedirect(urllib.request.HTTPRedirectHandler):
        def redirect_request(self, *args: Any, **kw: Any) -> None:
            return None

    def bound(*args: Any, **kw: Any) -> Any:
        import http.client

        return http.client.HTTPConnection(*args, source_address=(source_ip, 0), **kw)

    class _Handler(urllib.request.HTTPHandler):
        def http_open(self, req: Any) -> Any:
            return self.do_open(bound, req)

    opener = urllib.request.build_opener(_NoRedirect, _Handler)
    try:
        with opener.open(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
            return r.status, dict(r.headers.items()), r.read()
    except urllib.error.HTTPError as e:
        with contextlib.closing(e):
            return e.code, dict(e.headers.items()), e.read()


def scrape(port: int) -> Samples:
    """``/metrics`` of the server on ``port``, parsed by :mod:`posecast.testing.serve`."""
    status, body = serve_http_get(port, "/metrics")
    assert status == 200, status
    return parse_series(body)


def errors_by_code(samples: Samples) -> dict[str, float]:
    return {
        dict(labels)["code"]: v
        for (name, labels), v in samples.items()
        if name == "posecast_errors_total"
    }


def token_refusals(samples: Samples) -> dict[str, float]:
    """``posecast_token_refusals_total`` by reason."""
    return {
        dict(labels)["reason"]: v
        for (name, labels), v in samples.items()
        if name == "posecast_token_refusals_total"
    }


def delta(after: dict[str, float], before: dict[str, float]) -> dict[str, float]:
    out = {k: after.get(k, 0.0) - before.get(k, 0.0) for k in set(after) | set(before)}
    return {k: v for k, v in out.items() if v}


# --- the arena: a server process and a healthy-players process ------------------------


@dataclass
class Rates:
    """One measured window: poses per second each watched receiver got of its partner
    (measured in the healthy players' process), and the server's own counters over
    the same window: ticks delivered and poses produced, per second."""

    seconds: float
    hz: dict[tuple[str, str], float]
    server_ticks_hz: float = 0.0
    server_poses_hz: float = 0.0

    def worst_ratio(self, baseline: Rates) -> float:
        """The lowest of the client-side rates and the server-side rates, each as a
        share of the baseline."""
        ratios = [self.hz[k] / baseline.hz[k] for k in baseline.hz]
        ratios.append(self.server_ticks_hz / baseline.server_ticks_hz)
        ratios.append(self.server_poses_hz / baseline.server_poses_hz)
        return min(ratios)

    def __str__(self) -> str:
        pairs = ", ".join(f"{s}->{r} {hz:.1f} Hz" for (r, s), hz in sorted(self.hz.items()))
        return (
            f"{pairs}; server {self.server_ticks_hz:.1f} ticks/s, "
            f"{self.server_poses_hz:.1f} poses/s over {self.seconds:.1f} s"
        )


def serve_flags(cfg: ServerConfig) -> list[str]:
    """``posecast serve`` flags that rebuild ``cfg`` (every option that differs from
    the default, except the secret and key set, which travel in the environment)."""
    default = ServerConfig(token_secret=cfg.token_secret)
    flags: list[str] = []
    for name in ServerConfig.__dataclass_fields__:
        value = getattr(cfg, name)
        if name in (
            "token_secret",
            "token_keys",
            "port",
            "samples",
            "lookahead",
        ) or value == getattr(default, name):
            continue
        flag = "--" + name.replace("_", "-")
        if isinstance(value, bool):
            assert value, f"{name}: serve has no flag to turn it off"
            flags.append(flag)
        else:
            flags += [flag, str(value)]
    return flags


SETTLE_S = 1.0  # after the first poses, before any baseline: the streams settle


def cpu_split() -> tuple[set[int], set[int]] | None:
    """The cores the server has to itself, and the ones everyone else (the healthy
    players, the test's process and the attackers it starts) is confined to: half and
    half; the server may use the others' cores too. ``None`` on one core.

    In the field the attacker runs on another machine, so the only server CPU an attack
    may cost is what the server spends on it. On a shared 2-core machine three busy
    processes would otherwise take the server's core time by the scheduler's fairness
    alone, and the rates measured would say how fast the machine is, not how the
    server copes (a slower machine failed where a faster one passed)."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        return None
    half = len(cpus) // 2
    return set(cpus[:half]), set(cpus[half:])


class Arena:
    """``with Arena(cfg) as arena``: a ``posecast serve`` process built from ``cfg``
    (:class:`~posecast.testing.serve.ServeProcess`) and the healthy players streaming
    to it from a process of their own (``tests/system/reliability/healthy_players.py``).
    Only the attacker runs in the test's process."""

    def __init__(self, cfg: ServerConfig, *, nice: int = 0) -> None:
        """``nice``: the niceness of the server and the healthy players' process. A
        negative one (where the test may set it: root, as in CI) keeps whatever else
        runs on the machine, outside the test, from taking their CPU: what the arena
        measures is the hostile traffic's cost, not the machine's other load."""
        self._nice = nice
        # The tracker passes (head and hands on their trackers, the elbows' hinges) are
        # numpy run per tick, whose cost the engine benchmarks measure; what an arena
        # measures is whether hostile traffic reaches the healthy players, so it runs
        # without them and keeps the tick's headroom on a slower machine.
        self.cfg = cfg = dataclasses.replace(cfg, no_upper_ik=True, no_elbow_hinge=True)
        self.clients = tuple(p for players in HEALTHY.values() for p in players)
        self.server: ServeProcess | None = None
        self._players: subprocess.Popen[str] | None = None
        self.port = 0
        self._split = cpu_split()
        self._affinity = os.sched_getaffinity(0)

    def __enter__(self) -> Arena:
        split = self._split
        self.server = ServeProcess(
            *serve_flags(self.cfg),
            secret=self.cfg.token_secret,
            samples=self.cfg.samples,
            lookahead=self.cfg.lookahead,
            env={
                "POSECAST_LAYOUTS": Layout.HMD3_WAIST.value,  # one model: a faster start
                **({"POSECAST_TOKEN_KEYS": self.cfg.token_keys} if self.cfg.token_keys else {}),
            },
            preexec_fn=self._renice,
        )
        if split:  # this process, the attackers it starts and the healthy players
            os.sched_setaffinity(0, split[1])
        self.port = self.server.port
        try:
            self.server.wait_ready()
            self._players = subprocess.Popen(
                [sys.executable, "-m", "tests.system.reliability.healthy_players", str(self.port)],
                cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                preexec_fn=self._renice,
            )  # fmt: skip
            assert self._players.stdout is not None
            line = self._players.stdout.readline()
            if json.loads(line or "{}").get("ready") is not True:
                raise RuntimeError(f"the healthy players did not start: {line!r}")
            time.sleep(SETTLE_S)
        except BaseException:
            self.__exit__()
            raise
        return self

    def _renice(self) -> None:
        if self._nice:
            with contextlib.suppress(PermissionError):
                os.nice(self._nice)

    def __exit__(self, *exc: object) -> None:
        os.sched_setaffinity(0, self._affinity)
        if self._players is not None:
            if self._players.stdin is not None:
                with contextlib.suppress(OSError):
                    self._players.stdin.close()
            try:
                self._players.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._players.kill()
                self._players.wait()
            if self._players.stdout is not None:
                self._players.stdout.close()
        if self.server is not None:
            self.server.stop()

    def report(self) -> dict[str, Any]:
        """What the healthy players' process has seen so far."""
        assert self._players is not None and self._players.stdin is not None
        assert self._players.stdout is not None
        self._players.stdin.write("report\n")
        self._players.stdin.flush()
        out: dict[str, Any] = json.loads(self._players.stdout.readline())
        return out

    def counts(self) -> tuple[float, dict[tuple[str, str], int], float, float]:
        assert self.server is not None
        m = self.server.metrics()
        rep = self.report()
        counts = {(r, s): rep["counts"][f"{r}<-{s}"] for r, s in WATCHED}
        return rep["t"], counts, m["posecast_ticks_total"], m["posecast_poses_total"]

    @contextlib.contextmanager
    def window(self) -> Iterator[list[Rates]]:
        """``with arena.window() as out:`` measures the rates over the block."""
        out: list[Rates] = []
        t0, c0, ticks0, poses0 = self.counts()
        yield out
        t1, c1, ticks1, poses1 = self.counts()
        dt = t1 - t0
        hz = {k: (c1[k] - c0[k]) / dt for k in c0}
        out.append(Rates(dt, hz, (ticks1 - ticks0) / dt, (poses1 - poses0) / dt))

    def baseline(self, seconds: float = 2.0) -> Rates:
        with self.window() as out:
            time.sleep(seconds)
        return out[0]

    def errors_of(self, player: str) -> list[str]:
        """The error codes ``player`` has received."""
        codes: list[str] = self.report()["errors"][player]
        return codes

    def closed(self) -> list[str]:
        """The healthy players whose connection has closed."""
        closed: list[str] = self.report()["closed"]
        return closed


# Under attack, every healthy stream, and the server's own tick and pose counters,
# must keep this share of their baseline rate. The server, the healthy players and
# the attacker are three processes, and the last two are kept off half the cores
# (cpu_split), so the attacker's own CPU is not charged to the server (it would be on
# another machine in the field).
RATE_FLOOR = 0.9


def assert_rates_kept(during: Rates, baseline: Rates, what: str) -> None:
    ratio = during.worst_ratio(baseline)
    print(f"{what}: baseline {baseline}; during {during}; worst ratio {ratio:.2f}")
    assert ratio >= RATE_FLOOR, f"{what}: pose rate fell to {ratio:.0%} of baseline"
