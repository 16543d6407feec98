"""A ``posecast serve`` subprocess for tests and benchmarks: start, wait ready, read
``/metrics``, the process's RSS, CPU and file descriptors, stop.

One helper for the reliability suite, the scale-out tests and ``benchmarks/``, so
they all measure a server the same way: a real process on a loopback port, reading
its own counters, never the client's view alone::

    with ServeProcess(secret=SECRET, samples=8) as server:
        server.wait_ready()
        before = server.metrics()
        ...
        print(server.metric("posecast_poses_total") - before["posecast_poses_total"])

Standard library and ``prometheus_client`` (a serving dependency) only.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Self

from prometheus_client.parser import text_string_to_metric_families

Metrics = dict[str, float]  # "name{label="value",...}" (labels sorted) or "name" -> value
_LISTENING = re.compile(r"listening on ws://[\d.]+:(\d+)")


def http_get(port: int, path: str, timeout_s: float = 5.0) -> tuple[int, str]:
    """``GET path`` on a loopback server: status and body, error statuses included."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=timeout_s) as r:
            return int(r.status), r.read().decode()
    except urllib.error.HTTPError as e:
        with contextlib.closing(e):
            return e.code, e.read().decode()


Series = tuple[str, tuple[tuple[str, str], ...]]  # (name, sorted (label, value) pairs)
_LABEL = re.compile(r'(\w+)="((?:[^"\\]|\\.)*)"')


def _escape(value: str) -> str:
    """A label value as the exposition format writes it between quotes."""
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def series_name(name: str, labels: Mapping[str, str]) -> str:
    """The key :func:`parse_metrics` uses: ``name{a="x",b="y"}`` with sorted labels
    (values escaped as in the exposition format)."""
    if not labels:
        return name
    inner = ",".join(f'{k}="{_escape(v)}"' for k, v in sorted(labels.items()))
    return f"{name}{{{inner}}}"


def parse_series(text: str) -> dict[Series, float]:
    """Prometheus exposition text -> {(name, sorted label pairs): value}."""
    out: dict[Series, float] = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = float(s.value)
    return out


def parse_metrics(text: str) -> Metrics:
    """Prometheus exposition text -> {series: value} (see :func:`series_name`)."""
    return {series_name(n, dict(labels)): v for (n, labels), v in parse_series(text).items()}


def metric_sum(metrics: Metrics, name: str, **labels: str) -> float:
    """Sum of every series of ``name`` whose labels include ``labels``. ``name`` may
    carry labels too, as PromQL writes them: ``posecast_errors_total{code="TOO_LARGE"}``."""
    base_name, _, inline = name.partition("{")
    want = dict(_LABEL.findall(inline)) | {k: _escape(v) for k, v in labels.items()}
    total = 0.0
    for series, value in metrics.items():
        base, _, rest = series.partition("{")
        if base == base_name and want.items() <= dict(_LABEL.findall(rest)).items():
            total += value
    return total


def rss_bytes(pid: int) -> int:
    """Resident set size of process ``pid`` (Linux ``/proc``)."""
    status = Path(f"/proc/{pid}/status").read_text()
    found = re.search(r"^VmRSS:\s+(\d+) kB$", status, re.M)
    if found is None:
        raise RuntimeError(f"no VmRSS for process {pid}")
    return int(found[1]) * 1024


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of process ``pid`` so far, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def process_tree(pid: int) -> list[int]:
    """``pid`` and every live process below it (``posecast serve --workers N``: the
    supervisor and its workers)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        with contextlib.suppress(OSError):
            for task in os.listdir(f"/proc/{p}/task"):
                text = Path(f"/proc/{p}/task/{task}/children").read_text()
                todo += [int(c) for c in text.split()]
    return out


def _tree_sum(pid: int, of: Callable[[int], float]) -> float:
    total = 0.0
    for p in process_tree(pid):
        with contextlib.suppress(OSError, RuntimeError):  # one that exited meanwhile
            total += of(p)
    return total


class ServeProcess:
    """``python -m posecast serve --port 0`` with ``flags``; the port is read from its
    first line. The environment is this process's minus every ``POSECAST_*``, plus
    ``POSECAST_TOKEN_SECRET=secret``, ``POSECAST_LOG_LEVEL`` and ``env``.

    ``samples``, ``lookahead``: None leaves the server's default.
    ``log``: a file that receives the server's JSON log lines (stderr), else dropped.
    ``preexec_fn``: run in the child before it starts (CPU affinity, niceness).
    ``workers``: ``POSECAST_WORKERS`` (1, the single process, unless a test asks for
    the supervisor and its workers: then RSS, CPU and FDs are the whole tree's).
    """

    def __init__(
        self,
        *flags: str,
        secret: str,
        samples: int | None = 8,
        lookahead: int | None = 2,
        log: Path | None = None,
        log_level: str = "WARNING",
        env: Mapping[str, str] | None = None,
        preexec_fn: Callable[[], None] | None = None,
        workers: int | str = 1,
    ) -> None:
        full_env = {k: v for k, v in os.environ.items() if not k.startswith("POSECAST_")}
        full_env.update(POSECAST_TOKEN_SECRET=secret, POSECAST_LOG_LEVEL=log_level)
        full_env.update(POSECAST_WORKERS=str(workers))
        full_env.update(env or {})
        self.cmd = [sys.executable, "-m", "posecast", "serve", "--port", "0"]
        if samples is not None:
            self.cmd += ["--samples", str(samples)]
        if lookahead is not None:
            self.cmd += ["--lookahead", str(lookahead)]
        self.cmd += flags
        self.log = log
        err = log.open("ab") if log is not None else None
        try:
            self.proc = subprocess.Popen(
                self.cmd,
                env=full_env,
                stdout=subprocess.PIPE,
                stderr=err or subprocess.DEVNULL,
                text=True,
                preexec_fn=preexec_fn,
            )
        finally:
            if err is not None:
                err.close()
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()  # blocks until it listens (or dies)
        match = _LISTENING.search(line)
        if not match:
            self.stop()
            tail = log.read_text(errors="replace")[-2000:] if log is not None else ""
            raise RuntimeError(f"posecast serve did not start: {line!r} {tail}")
        self.port = int(match.group(1))

    # --- context manager -------------------------------------------------------------

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # --- what a test reads -------------------------------------------------------------

    @property
    def pid(self) -> int:
        return self.proc.pid

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/"

    def http(self, path: str, timeout_s: float = 5.0) -> tuple[int, str]:
        return http_get(self.port, path, timeout_s)

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        """Until ``/readyz`` answers 200 (the engine is loaded, the bus is up)."""
        deadline = time.monotonic() + timeout_s
        while True:
            with contextlib.suppress(OSError):
                if self.http("/readyz")[0] == 200:
                    return
            if self.proc.poll() is not None:
                raise RuntimeError(f"posecast serve exited with {self.proc.returncode}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"posecast serve not ready in {timeout_s} s")
            time.sleep(0.05)

    def alive(self) -> bool:
        try:
            return self.proc.poll() is None and self.http("/healthz")[0] == 200
        except OSError:
            return False

    def metrics(self) -> Metrics:
        status, body = self.http("/metrics")
        if status != 200:
            raise RuntimeError(f"/metrics answered {status}")
        return parse_metrics(body)

    def metric(self, name: str, **labels: str) -> float:
        """Sum of every series of metric ``name`` (matching ``labels``) right now."""
        return metric_sum(self.metrics(), name, **labels)

    def rss_bytes(self) -> int:
        return int(_tree_sum(self.pid, rss_bytes))

    def cpu_seconds(self) -> float:
        return _tree_sum(self.pid, cpu_seconds)

    def fds(self) -> int:
        return int(_tree_sum(self.pid, lambda p: len(os.listdir(f"/proc/{p}/fd"))))

    # --- stopping ------------------------------------------------------------------------

    def kill(self) -> None:
        """SIGKILL: the node dies without a word."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=10)

    def stop(self, timeout_s: float = 20.0) -> int:
        """SIGTERM (graceful: ``bye`` to all, drain), SIGKILL past ``timeout_s``; the
        exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.kill()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        return int(self.proc.returncode)
