"""A scripted session against a running posecast server (CONFORMANCE.md, part 3).

    posecast serve --dev                       # prints "token secret for this run: S"
    python proto/conformance.py ws://127.0.0.1:8765/ --secret S

It starts nothing itself: it connects to the URL it is given, mints its tokens from
the secret as README.md ("Join tokens") says, and walks through the session of each
protocol version, checking every answer against the spec and every server message
against ``schema.json``. It prints one line per check and exits 0 when all pass.

Needs Python 3.11+, ``websockets``, ``msgpack`` and ``jsonschema`` (all three in the
server's own environment); nothing of posecast's, so it is also a worked example of a
client written from this folder alone (``datamodel.py`` beside it renders messages).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import hashlib
import hmac
import json
import secrets
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
from jsonschema import Draft202012Validator
from referencing import Registry, Resource
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from datamodel import render  # noqa: E402

SCHEMA = json.loads((HERE / "schema.json").read_text("utf-8"))
_REGISTRY = Registry().with_resource(SCHEMA["$id"], Resource.from_contents(SCHEMA))
VALIDATORS = {
    v: Draft202012Validator({"$ref": f"{SCHEMA['$id']}#/$defs/v{v}"}, registry=_REGISTRY)
    for v in (1, 2)
}
IDENTITY = [0.0, 0.0, 0.0, 1.0]
# The reference body standing in its T-pose (skeleton.md): head, hands, waist.
TPOSE = [[0.0, 1.6, 0.0], [0.7, 1.45, 0.0], [-0.7, 1.45, 0.0], [0.0, 0.98, 0.0]]
WAIT_S = 5.0


class CheckFailedError(AssertionError):
    """A check that did not hold."""


def mint(secret: str, room: str, player: str, ttl_s: int = 600) -> str:
    """A join token, exactly as README.md's "Join tokens" describes it: a JWT, HS256
    with the secret, built here from the standard library (no JWT library: this file
    is an implementation of the spec of its own)."""

    def b64(raw: bytes) -> str:
        return base64.urlsafe_b64encode(raw).rstrip(b"=").decode("ascii")

    def part(value: dict[str, object]) -> str:
        return b64(json.dumps(value, separators=(",", ":")).encode("utf-8"))

    now = int(time.time())
    claims: dict[str, object] = {
        "room": room,
        "player": player,
        "role": "player",
        "iat": now,
        "exp": now + ttl_s,
        "jti": b64(secrets.token_bytes(12)),
    }
    signed = part({"alg": "HS256", "typ": "JWT"}) + "." + part(claims)
    mac = hmac.new(secret.encode("utf-8"), signed.encode("ascii"), hashlib.sha256).digest()
    return signed + "." + b64(mac)


def pack(message: dict[str, Any]) -> bytes:
    out: bytes = msgpack.packb(message, use_bin_type=True)
    return out


def frame(seq: int, t: float, sway: float = 0.0) -> dict[str, Any]:
    rows = [[p[0] + sway, p[1], p[2], *IDENTITY] for p in TPOSE]
    return {"type": "frame", "seq": seq, "t": t, "trackers": rows}


class Session:
    """One connection: every message it gets is rendered, schema-checked and kept."""

    def __init__(self, ws: ClientConnection, version: int) -> None:
        self.ws, self.version = ws, version
        self.got: list[dict[str, Any]] = []
        self.close_code: int | None = None
        self._new = asyncio.Event()
        self._reader = asyncio.create_task(self._read())

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                if not isinstance(data, bytes):
                    raise CheckFailedError("the server sent a text message")
                message = render(data)
                errors = [e.message for e in VALIDATORS[self.version].iter_errors(message)]
                if errors:
                    raise CheckFailedError(
                        f"a {message.get('type')} fails schema.json: {errors[0]}"
                    )
                self.got.append(message)
                self._new.set()
        except ConnectionClosed:
            pass
        finally:
            self.close_code = self.ws.close_code
            self._new.set()

    async def send(self, message: dict[str, Any] | str) -> None:
        await self.ws.send(message if isinstance(message, str) else pack(message))

    async def expect(self, what: str, match: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
        """The first message (kept or to come) that ``match``es, else :class:`CheckFailedError`."""
        deadline = time.monotonic() + WAIT_S
        while True:
            for m in self.got:
                if match(m):
                    return m
            if self._reader.done():
                self._reader.result()  # a CheckFailedError from the reader
                raise CheckFailedError(f"closed ({self.close_code}) before {what}")
            left = deadline - time.monotonic()
            if left <= 0:
                raise CheckFailedError(f"no {what} within {WAIT_S} s")
            self._new.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._new.wait(), left)

    async def closed(self) -> int | None:
        try:
            await asyncio.wait_for(asyncio.shield(self._reader), WAIT_S)
        except TimeoutError:
            raise CheckFailedError(f"the server did not close within {WAIT_S} s") from None
        return self.close_code


def _error(code: str) -> Callable[[dict[str, Any]], bool]:
    return lambda m: m["type"] == "error" and m["code"] == code


async def open_session(url: str, version: int) -> Session:
    offer = ["posecast.v2", "posecast.v1"] if version == 2 else ["posecast.v1"]
    ws = await connect(url, subprotocols=offer)  # type: ignore[arg-type]
    if ws.subprotocol != f"posecast.v{version}":
        raise CheckFailedError(f"offered {offer}, the server chose {ws.subprotocol}")
    return Session(ws, version)


async def joined(url: str, secret: str, version: int, room: str, player: str) -> Session:
    s = await open_session(url, version)
    hello = {"type": "hello", "version": version, "token": mint(secret, room, player)}
    await s.send({**hello, "room": room, "name": f"conformance v{version}"})
    welcome = await s.expect("welcome", lambda m: m["type"] in ("welcome", "error"))
    if welcome["type"] == "error":
        raise CheckFailedError(f"hello refused: {welcome['code']} {welcome['message']}")
    if (welcome["version"], welcome["player"], welcome["room"]) != (version, player, room):
        raise CheckFailedError(
            f"welcome says {welcome['version']}, {welcome['player']}, {welcome['room']}"
        )
    return s


async def session_checks(
    url: str, secret: str, version: int, report: Callable[[str], None]
) -> None:
    """The session of one protocol version: join, calibrate, stream, ping, errors, bye."""
    room, player = f"conformance-{secrets.token_hex(3)}", f"c{version}-{secrets.token_hex(3)}"
    s = await joined(url, secret, version, room, player)
    report(f"v{version}: posecast.v{version} chosen; welcome names the token's player and room")

    await s.send({"type": "calibrate", "height_m": 1.75})
    t0 = 1000.0
    await s.send({"type": "ping", "t0": t0})
    pong = await s.expect("pong", lambda m: m["type"] == "pong")
    if pong["t0"] != t0 or pong["t1"] > pong["t2"]:
        raise CheckFailedError(f"pong {pong}")
    report(f"v{version}: pong echoes t0, t1 <= t2")

    start = time.monotonic()
    for seq in range(90):  # 1.5 s at 60 Hz
        await s.send(frame(seq, start + seq / 60.0, sway=0.001 * seq))
        await asyncio.sleep(1 / 60)
    if version == 1:
        pose = await s.expect("pose", lambda m: m["type"] == "pose" and m["player"] == player)
        if not 0 <= pose["seq"] < 90:
            raise CheckFailedError(f"a pose of seq {pose['seq']}, never sent")
        report(f"v{version}: poses of this player come back, seq echoed")
    else:
        poses = await s.expect("poses", lambda m: m["type"] == "poses" and m["data"]["$bin"])
        if not poses["data"]["$bin"]:
            raise CheckFailedError("an empty poses")
        report(f"v{version}: poses messages with records come back")
    if any(m["type"] == "skeleton" for m in s.got):
        raise CheckFailedError("calibrating to 1.75 m (scale 1) sent a skeleton")
    if any(m["type"] == "error" for m in s.got):
        raise CheckFailedError(f"an error: {next(m for m in s.got if m['type'] == 'error')}")

    await s.send(frame(89, start + 1.5))
    dup = await s.expect("DUPLICATE", _error("DUPLICATE"))
    if dup["fatal"] or dup.get("field") != "seq" or dup.get("ref_seq") != 89:
        raise CheckFailedError(f"DUPLICATE answered {dup}")
    await s.send({"type": "teleport"})
    unknown = await s.expect("UNKNOWN_TYPE", _error("UNKNOWN_TYPE"))
    if unknown["fatal"]:
        raise CheckFailedError("UNKNOWN_TYPE was fatal")
    report(f"v{version}: DUPLICATE and UNKNOWN_TYPE answered, not fatal")

    await s.send({"type": "bye", "reason": "done"})
    await s.expect("bye", lambda m: m["type"] == "bye")
    if (code := await s.closed()) != 1000:
        raise CheckFailedError(f"closed {code} after bye, not 1000")
    report(f"v{version}: bye answered by bye, close 1000")


async def refusal_checks(url: str, secret: str, report: Callable[[str], None]) -> None:
    """A text message (1003), and a hello of the wrong version (1008)."""
    s = await open_session(url, 1)
    await s.send("hello")
    err = await s.expect("MALFORMED", _error("MALFORMED"))
    code = await s.closed()
    if not err["fatal"] or code != 1003:
        raise CheckFailedError(f"a text message: {err}, close {code}")
    report("a text message: MALFORMED, fatal, close 1003")

    s = await open_session(url, 1)
    room = f"conformance-{secrets.token_hex(3)}"
    token = mint(secret, room, f"c-{secrets.token_hex(3)}")
    await s.send({"type": "hello", "version": 2, "token": token, "room": room, "name": "x"})
    err = await s.expect("VERSION_UNSUPPORTED", _error("VERSION_UNSUPPORTED"))
    code = await s.closed()
    if not err["fatal"] or code != 1008:
        raise CheckFailedError(f"hello.version 2 on posecast.v1: {err}, close {code}")
    report("hello.version 2 on posecast.v1: VERSION_UNSUPPORTED, fatal, close 1008")


async def run(url: str, secret: str, report: Callable[[str], None] = print) -> None:
    """Every check against the server at ``url``; :class:`CheckFailedError` at the first
    that fails."""
    for version in (1, 2):
        await session_checks(url, secret, version, report)
    await refusal_checks(url, secret, report)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("url", help="the server's WebSocket URL, e.g. ws://127.0.0.1:8765/")
    parser.add_argument("--secret", required=True, help="its token secret (--dev prints it)")
    args = parser.parse_args(argv)
    try:
        asyncio.run(run(args.url, args.secret, lambda line: print(f"PASS  {line}")))
    except (CheckFailedError, OSError) as exc:
        print(f"FAIL  {exc}")
        return 1
    print("all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
