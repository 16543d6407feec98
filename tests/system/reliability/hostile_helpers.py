"""Shared pieces of the hostile-input tests (``test_hostile_*.py``); the arena (a
server and healthy players) is :mod:`tests.system.reliability.arena`, the flooder and
churner processes :mod:`tests.system.reliability.flooder`.

* :class:`Attacker`: a blocking WebSocket client (``websockets.sync``) that the test
  drives from the main thread, optionally from another loopback source address
  (``127.0.0.2``: "another IP" for the per-IP limits).
* :func:`verdict`: the spec's answer to a message from a joined client (the codec
  for the envelope and fields, then the role table and ``seq`` rules of
  ``proto/README.md``), so the fuzzer knows what the server must answer.
"""

from __future__ import annotations

import contextlib
import json
import socket
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

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
from tests.online.conftest import make_cfg, token
from tests.system.reliability.arena import REPO

PROTO = REPO / "proto"
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
