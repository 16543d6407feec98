"""Shared pieces of the hostile-input tests (``test_hostile_*.py``).

* :class:`Arena`: a real ``posecast serve`` process plus healthy players in a
  process of their own (``healthy_players.py``). Two players stream walk frames at
  60 Hz in room ``r1``, two more in room ``r2``; the arena counts the poses each
  receives of its partner, and reads the server's tick and pose counters, so a test
  can compare the rates during an attack with a baseline window taken just before.
* :class:`Attacker`: a blocking WebSocket client (``websockets.sync``) that the test
  drives from the main thread, optionally from another loopback source address
  (``127.0.0.2``: "another IP" for the per-IP limits).
* :func:`verdict`: the spec's answer to a message from a joined client (the codec
  for the envelope and fields, then the role table and ``seq`` rules of
  ``proto/README.md``), so the fuzzer knows what the server must answer.
* :func:`scrape`: ``/metrics`` parsed into ``{(name, labels): value}``.

Run as a module, this file is also the message flooder of ``test_hostile_floods`` and
the reconnecting churner of ``test_hostile_churn``: a separate process each.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import msgpack
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from posecast.errors import ConfigError, ProtocolError
from posecast.online.config import ServerConfig
from posecast.online.engine.calibration import Calibration
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    DEFAULT_LIMITS,
    ROLE_MAY_SEND,
    ROLE_MAY_SEND_V2,
    SUBPROTOCOLS,
    Bye,
    Calibrate,
    Error,
    Frame,
    Hello,
    Limits,
    Message,
    Ping,
    Pong,
    Pose,
    Poses,
    Welcome,
    seq_delta,
)
from posecast.testing.serve import Series, ServeProcess, parse_series
from posecast.testing.serve import http_get as serve_http_get
from posecast.tracking.layouts import Layout
from tests.online.conftest import make_cfg, token, walk_frame
from tests.system.reliability.healthy_players import HEALTHY, WATCHED

PROTO = Path(__file__).resolve().parents[3] / "proto"
REPO = PROTO.parent
OTHER_IP = "127.0.0.2"  # Linux routes all of 127/8 to lo: a second client address


# --- the vectors and the error table -------------------------------------------------


def vectors(version: int = 1) -> list[dict[str, Any]]:
    """The single-message cases that hold in protocol ``version`` (the attackers here
    speak v1; the v2 cases go over v2 connections in tests/system/test_invalid_input.py)."""
    out: list[dict[str, Any]] = []
    for path in sorted((PROTO / "vectors").glob("*.json")):
        for case in json.loads(path.read_text("utf-8")):
            if version in case["versions"] and "messages" not in case:
                out.append({**case, "file": path.stem})
    return out


def invalid_vectors() -> list[dict[str, Any]]:
    return [v for v in vectors() if "error" in v]


def valid_encodings() -> list[bytes]:
    """Every valid encoding in the vectors: canonical and the also-accepted ones."""
    out = []
    for v in vectors():
        if "canonical_hex" in v:
            out += [bytes.fromhex(h) for h in (v["canonical_hex"], *v.get("also_accept_hex", ()))]
    return out


def base_maps() -> dict[str, list[dict[str, Any]]]:
    """The valid vectors' wire maps by type (``{"$bin": hex}`` turned into bytes)."""
    out: dict[str, list[dict[str, Any]]] = {}
    for v in vectors():
        if "canonical_hex" in v:
            m = msgpack.unpackb(bytes.fromhex(v["canonical_hex"]), raw=False)
            out.setdefault(m["type"], []).append(m)
    return out


def error_table() -> dict[str, bool]:
    """``{code: fatal}`` of ``proto/errors.json``."""
    return {e["code"]: e["fatal"] for e in json.loads((PROTO / "errors.json").read_text())}


def schema(version: int = 1) -> dict[str, Any]:
    """``proto/fields.json`` as protocol ``version`` has it: the other versions'
    messages and fields left out, a per-version ``const`` resolved."""
    out: dict[str, Any] = json.loads((PROTO / "fields.json").read_text("utf-8"))
    out["messages"] = {
        k: {**m, "fields": [f for f in m["fields"] if version in f.get("versions", [version])]}
        for k, m in out["messages"].items()
        if version in m.get("versions", [version])
    }
    for t in out["types"].values():
        if "fields" in t:
            t["fields"] = [f for f in t["fields"] if version in f.get("versions", [version])]
    for m in out["messages"].values():
        for f in m["fields"]:
            if "const_by_version" in f:  # hello.version: 1 on posecast.v1, 2 on posecast.v2
                f["const"] = f.pop("const_by_version")[str(version)]
    return out


# --- what the server must answer ------------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    """The answer the spec gives to one message from a joined client."""

    code: str | None  # None: accepted, no error
    fatal: bool = False
    field: str | None = None
    bye: bool = False  # the server says bye and closes (1000)
    close_code: int = 1008  # after a fatal error (1003 for a text message)


@dataclass
class Peer:
    """What the verdict needs to know of the sending connection."""

    role: str
    last_seq: int | None = None
    limits: Limits = DEFAULT_LIMITS
    version: int = 1  # the connection's protocol


def verdict(data: bytes | str, peer: Peer) -> Verdict:
    """The answer to ``data``; updates ``peer.last_seq`` for an accepted frame."""
    if isinstance(data, str):
        return Verdict("MALFORMED", True, close_code=1003)  # text: 1003 (Transport)
    try:
        cap = peer.limits.max_message_bytes  # a server decodes within it (v2 too)
        msg = decode(data, limits=peer.limits, max_bytes=cap, version=peer.version)
    except ProtocolError as exc:
        return Verdict(exc.code, exc.fatal, exc.field)
    if isinstance(msg, Hello):
        return Verdict("ALREADY_JOINED", False, "type")
    may_send = ROLE_MAY_SEND_V2 if peer.version >= 2 else ROLE_MAY_SEND
    if msg.TYPE not in may_send[peer.role]:
        return Verdict("FORBIDDEN", False, "type")
    if isinstance(msg, Frame):
        if peer.last_seq is not None:
            d = seq_delta(msg.seq, peer.last_seq)
            if d == 0:
                return Verdict("DUPLICATE", False, "seq")
            if d < 0:
                return Verdict("OUT_OF_ORDER", False, "seq")
        if msg.sites:  # the attackers join with a named layout: trackers, never sites
            return Verdict("BAD_FIELD", False, "sites")  # refused: its seq counts for nothing
        peer.last_seq = msg.seq
        return Verdict(None)
    if isinstance(msg, Bye):
        return Verdict(None, bye=True)
    if isinstance(msg, Calibrate):
        if msg.sites:  # a tracker set's T-pose, from a player of a named layout
            return Verdict("BAD_FIELD", False, "sites")
        try:
            if msg.height_m is not None:
                Calibration.from_height(msg.height_m)
            else:
                assert msg.pos is not None and msg.quat is not None
                Calibration.from_tpose(msg.pos, msg.quat)
        except ConfigError:
            where = "height_m" if msg.height_m is not None else "trackers"
            return Verdict("CALIBRATION_FAILED", False, where)
        return Verdict(None)
    if msg.TYPE in ("selector", "kick"):
        # The fuzzing backend watches a room of its own with no players in it.
        return Verdict("NOT_FOUND", False, "player")
    return Verdict(None)  # ping: a pong


# --- a blocking attacker ----------------------------------------------------------------


@dataclass
class Answer:
    """What came back for one probe: errors, and whether the connection survived."""

    errors: list[Error] = field(default_factory=list)
    pong: bool = False
    bye: bool = False
    closed: bool = False
    close_code: int | None = None
    close_reason: str = ""


def open_socket(port: int, source_ip: str = "127.0.0.1") -> socket.socket:
    return socket.create_connection(("127.0.0.1", port), timeout=5, source_address=(source_ip, 0))


class Attacker:
    """One blocking client connection; :meth:`probe` sends a message and reports."""

    def __init__(self, port: int, *, source_ip: str = "127.0.0.1", version: int = 1) -> None:
        self.port = port
        self.source_ip = source_ip
        self.version = version
        self.ws: ClientConnection = connect(
            f"ws://127.0.0.1:{port}/",
            sock=open_socket(port, source_ip),
            subprotocols=[SUBPROTOCOLS[version]],  # type: ignore[list-item]
            compression=None,
            max_size=None,
            open_timeout=5,
        )
        self.ws.__enter__()  # websockets >= 17.1 wants the context-manager form
        self._marker = 0.0
        self.received: list[Message] = []

    def hello(self, tok: str, room: str = "r1", name: str = "Mallory", **kw: Any) -> Message:
        self.ws.send(encode(Hello(self.version, tok, room, name, **kw)))
        return self.next(lambda m: isinstance(m, Welcome | Error))

    def next(self, pred: Callable[[Message], bool], timeout_s: float = 5.0) -> Message:
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no matching message in {timeout_s} s")
            data = self.ws.recv(timeout=left)
            assert isinstance(data, bytes)
            msg = decode(data, version=self.version)
            if not isinstance(msg, Pose | Poses):
                self.received.append(msg)
            if pred(msg):
                return msg

    def probe(self, data: bytes | str, timeout_s: float = 5.0) -> Answer:
        """Send ``data``, then a ping; collect everything up to its pong or the close."""
        self._marker += 1.0
        marker = self._marker
        ans = Answer()
        with contextlib.suppress(ConnectionClosed):  # what came before the close is read below
            self.ws.send(data)
            self.ws.send(encode(Ping(marker)))
        try:
            deadline = time.monotonic() + timeout_s
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"neither a pong nor a close in {timeout_s} s")
                raw = self.ws.recv(timeout=left)
                assert isinstance(raw, bytes)
                msg = decode(raw, version=self.version)
                if isinstance(msg, Error):
                    ans.errors.append(msg)
                elif isinstance(msg, Bye):
                    ans.bye = True
                elif isinstance(msg, Pong) and msg.t0 == marker:
                    ans.pong = True
                    return ans
        except ConnectionClosed:
            ans.closed = True
            rcvd = self.ws.close_code
            ans.close_code, ans.close_reason = rcvd, self.ws.close_reason or ""
            return ans

    def close(self) -> None:
        self.ws.close()


def check_answer(v: Verdict, ans: Answer, table: dict[str, bool]) -> list[str]:
    """Where ``ans`` differs from ``v`` (empty: as the spec says)."""
    problems = []
    codes = [(e.code, e.fatal, e.field) for e in ans.errors]
    if v.code is None:
        if codes:
            problems.append(f"accepted message answered with {codes}")
        if v.bye and not (ans.bye and ans.closed and ans.close_code == 1000):
            problems.append(f"bye not answered with bye + 1000: {ans}")
        if not v.bye and not ans.pong:
            problems.append(f"connection lost after an accepted message: {ans}")
        return problems
    if codes != [(v.code, v.fatal, v.field)]:
        problems.append(f"want [{(v.code, v.fatal, v.field)}], got {codes}")
    if v.fatal != table[v.code]:
        problems.append(f"{v.code} fatal={v.fatal} but errors.json says {table[v.code]}")
    if v.fatal:
        if not ans.closed or (ans.close_code, ans.close_reason) != (v.close_code, v.code):
            problems.append(f"fatal {v.code}: want close {v.close_code}, got {ans}")
    elif not ans.pong:
        problems.append(f"non-fatal {v.code} lost the connection: {ans}")
    return problems


class AttackPair:
    """The fuzzers' two attacker connections, a player in ``r1`` and a backend in a room
    of its own (its selectors and kicks reach no healthy player), each reconnected with
    a fresh token when the server closes it. :meth:`send` is one probe: what the spec
    says the server must answer (:func:`verdict`), what it did, and the codes counted.
    """

    def __init__(self, port: int, version: int = 1) -> None:
        self.port, self.version = port, version
        self.table = error_table()
        self.att: dict[str, Attacker] = {}
        self.peer: dict[str, Peer] = {}
        self.expected: Counter[str] = Counter()  # error codes the answers must carry
        self.sent: Counter[str] = Counter()  # messages, by the caller's label
        self.joins = 0
        self.reconnects = 0  # joins after the server closed an attacker
        for role in ("player", "backend"):
            self._join(role)

    def _join(self, role: str) -> None:
        self.joins += 1
        tag = f"v{self.version}-{self.joins}"
        att = Attacker(self.port, version=self.version)
        if role == "player":
            welcome = att.hello(token("r1", f"atk-player-{tag}"))
        else:
            welcome = att.hello(token("rb", f"atk-backend-{tag}", role="backend"), room="rb")
        assert isinstance(welcome, Welcome) and welcome.version == self.version, welcome
        self.att[role], self.peer[role] = att, Peer(role, version=self.version)

    def send(self, role: str, data: bytes, label: str = "") -> None:
        v = verdict(data, self.peer[role])
        ans = self.att[role].probe(data)
        self.sent[label] += 1
        if v.code is not None:
            self.expected[v.code] += 1
        if ans.closed:
            self.reconnects += 1
            self._join(role)
        problems = check_answer(v, ans, self.table)
        assert not problems, f"{label} ({role}) {data[:64]!r}...: {problems}"

    def close(self) -> None:
        for att in self.att.values():
            att.close()


def fuzz_arena_cfg() -> ServerConfig:
    """The fuzzers' server: every non-fatal error answered and no frame rate-limited,
    so each message's answer is exact (test_hostile_floods covers the limits), and the
    per-IP and node-wide connection budgets (test_hostile_churn) opened up, since a
    fuzzer reconnects after every fatal error as fast as it can."""
    return make_cfg(
        lookahead=1, error_rate_hz=1e6, control_rate_hz=1e6, rate_burst=10**6, max_rooms=16,
        fatal_per_ip_per_min=10**6, accepts_per_s=1e6,
    )  # fmt: skip


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


# --- the flooder (a separate process) ------------------------------------------------------


def _flood(args: argparse.Namespace) -> dict[str, Any]:
    """Join, then send ``kind`` messages as fast as the socket takes them."""
    att = Attacker(args.port, source_ip=args.source_ip)
    welcome = att.hello(args.token, room=args.room)
    assert isinstance(welcome, Welcome), welcome
    errors: dict[str, int] = {}
    stop = threading.Event()

    def read() -> None:
        with contextlib.suppress(ConnectionClosed, TimeoutError):
            while not stop.is_set():
                raw = att.ws.recv(timeout=1.0)
                assert isinstance(raw, bytes)
                msg = decode(raw)
                if isinstance(msg, Error):
                    errors[msg.code] = errors.get(msg.code, 0) + 1

    reader = threading.Thread(target=read)
    reader.start()
    walk_frame(0, seed=5)  # builds the walk clip (seconds) before the clock starts
    sent, seq = 0, 0
    junk = msgpack.packb({"type": "x-flood", "n": 1})
    t0 = time.monotonic()
    with contextlib.suppress(ConnectionClosed):
        while time.monotonic() - t0 < args.seconds:
            for _ in range(50):
                if args.kind == "frames":
                    data = encode(walk_frame(seq, seed=5))
                    seq += 1
                elif args.kind == "pings":
                    data = encode(Ping(float(sent)))
                else:
                    data = junk
                att.ws.send(data)
                sent += 1
    seconds = time.monotonic() - t0
    time.sleep(0.5)  # let the last replies arrive
    stop.set()
    reader.join()
    with contextlib.suppress(ConnectionClosed):
        att.close()
    return {"sent": sent, "seconds": seconds, "errors": errors}


def _churn(args: argparse.Namespace) -> dict[str, Any]:
    """Connect, join, send a message the codec refuses (fatal: MALFORMED), and do it
    again at once: ``attempts`` times from each of ``ips`` loopback addresses, round
    robin (``seconds`` at most)."""
    ips = [f"127.0.0.{10 + i}" for i in range(args.ips)]
    outcome: dict[str, int] = {}
    joins_per_ip = dict.fromkeys(ips, 0)
    t0, n = time.monotonic(), 0
    while n < args.attempts * len(ips) and time.monotonic() - t0 < args.seconds:
        ip = ips[n % len(ips)]
        n += 1
        try:
            att = Attacker(args.port, source_ip=ip)
        except Exception as exc:  # refused at the upgrade: HTTP 429 / 503
            status = getattr(getattr(exc, "response", None), "status_code", None)
            key = f"http_{status}" if status else type(exc).__name__
            outcome[key] = outcome.get(key, 0) + 1
            continue
        try:
            welcome = att.hello(args.token, room=args.room, name="Churn")
            if not isinstance(welcome, Welcome):
                outcome["refused"] = outcome.get("refused", 0) + 1
                continue
            joins_per_ip[ip] += 1
            ans = att.probe(b"\xc1")  # never valid msgpack
            key = "malformed" if [e.code for e in ans.errors] == ["MALFORMED"] else "other"
            outcome[key] = outcome.get(key, 0) + 1
        finally:
            with contextlib.suppress(Exception):
                att.close()
    return {"attempts": n, "seconds": time.monotonic() - t0, "outcome": outcome,
            "joins_per_ip": joins_per_ip}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="the attackers of test_hostile_floods and _churn")
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--token", required=True)
    p.add_argument("--room", default="r1")
    p.add_argument("--kind", choices=("frames", "pings", "junk", "churn"), required=True)
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--source-ip", default=OTHER_IP)
    p.add_argument("--ips", type=int, default=8, help="churn: source addresses to rotate")
    p.add_argument("--attempts", type=int, default=40, help="churn: attempts per address")
    args = p.parse_args(argv)
    print(json.dumps(_churn(args) if args.kind == "churn" else _flood(args)))


ATTACKER_NICE = 10
T = TypeVar("T")


def as_attacker(fn: Callable[[], T]) -> T:
    """Run ``fn`` in a thread of its own at niceness :data:`ATTACKER_NICE` (Linux nice
    is per thread, and the threads it starts, such as the sync WebSocket client's
    readers, inherit it), wait for it, and return its result or raise its exception.

    For attackers that must run in the test's process (the fuzzer: hypothesis drives
    it): in the field the attacker's CPU is on its own machine, so here it takes only
    what the server and the healthy players leave."""
    out: list[T] = []
    failure: list[BaseException] = []

    def run() -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), ATTACKER_NICE)
            out.append(fn())
        except BaseException as exc:  # handed to the caller below
            failure.append(exc)

    thread = threading.Thread(target=run, name="attacker")
    thread.start()
    thread.join()
    if failure:
        raise failure[0]
    return out[0]


def run_flooder(port: int, tok: str, kind: str, seconds: float, *extra: str) -> Any:
    """Start the flooder (or churner) process; ``.communicate()`` gives its JSON report.

    It runs at niceness :data:`ATTACKER_NICE`: in the field the attacker's CPU is on
    its own machine; on this one's two cores the kernel then serves the server and the
    healthy players first, and the attacker takes what is left (it still sends as
    fast as the server reads, which is what the test is about)."""
    return subprocess.Popen(
        [sys.executable, "-m", "tests.system.reliability.hostile_helpers", "--port", str(port),
         "--token", tok, "--kind", kind, "--seconds", str(seconds), *extra],
        cwd=REPO, stdout=subprocess.PIPE, text=True,
        preexec_fn=lambda: os.nice(ATTACKER_NICE),
    )  # fmt: skip


if __name__ == "__main__":
    main()
