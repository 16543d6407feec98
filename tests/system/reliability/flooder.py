"""The message flooder of ``test_hostile_floods`` and the reconnecting churner of
``test_hostile_churn``, each run as a separate process (``python -m
tests.system.reliability.flooder``, :func:`run_flooder`), and :func:`as_attacker` for the
attackers that run in the test's own process."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import msgpack
from websockets.exceptions import ConnectionClosed

from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    Error,
    Ping,
    Welcome,
)
from tests.online.conftest import walk_frame
from tests.system.reliability.hostile_helpers import OTHER_IP, REPO, Attacker

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
        [sys.executable, "-m", "tests.system.reliability.flooder", "--port", str(port),
         "--token", tok, "--kind", kind, "--seconds", str(seconds), *extra],
        cwd=REPO, stdout=subprocess.PIPE, text=True,
        preexec_fn=lambda: os.nice(ATTACKER_NICE),
    )  # fmt: skip


if __name__ == "__main__":
    main()
