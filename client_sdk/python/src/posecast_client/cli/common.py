"""What the command-line tools share: server options (flags, then ``POSECAST_*``
environment variables), token minting, signal handling, a patient connect, and the
error format (the server CLI's): a command-line mistake prints ``PROG: error
[CONFIG_INVALID]: ...`` and a ``hint:`` line and exits 2; a failure met while running
(:func:`describe`: the server refused, could not be reached, a file could not be read)
prints the same two lines with its own code and exits 1."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import re
import secrets
import signal
import sys
from collections.abc import Mapping
from typing import Any, NoReturn

from websockets.exceptions import InvalidHandshake, InvalidURI

from posecast_client.client import Client, check_url, connect
from posecast_client.codec import ID_PATTERN
from posecast_client.errors import (
    BvhError,
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
    ProtocolError,
    RecordingError,
)
from posecast_client.protocol import MAX_ID_BYTES
from posecast_client.tokens import MAX_TTL_S, mint_token, secret_problem

ENV_PREFIX = "POSECAST_"
CONFIG_INVALID = "CONFIG_INVALID"  # the server's code for a bad configuration value


# Codes of failures met at run time that are not the server's wire codes (those keep
# theirs: UNAUTHENTICATED, TOKEN_EXPIRED, BAD_FIELD, ...).
UNREACHABLE = "UNREACHABLE"  # no WebSocket session with the server at the URL
FILE_INVALID = "FILE_INVALID"  # a file to read or write: missing, unreadable, not the format
BVH_INVALID = "BVH_INVALID"  # a BVH file to replay (the server CLI's code for the same)

_WIRE_HINTS = {
    "UNAUTHENTICATED": "the token does not verify: use the secret the server was started "
    "with (`posecast serve --dev` prints it), or a token minted with it",
    "TOKEN_EXPIRED": "mint a new token, or pass --secret and let the tool mint them",
    "FORBIDDEN": "the token is for another room or role",
    "BAD_FIELD": "the server refused a value the tool sent (the message names it); a room "
    "name holds only letters, digits and _ . : -",
    "OUT_OF_RANGE": "a value sent was refused as out of range: see proto/README.md",
    "ROOM_FULL": "the room has no seat left: use another room or fewer players",
    "LAYOUT_UNSUPPORTED": "the server does not serve this layout: see its --layouts",
}


def print_error(prog: str, code: str, message: str, hint: str) -> None:
    """``prog: error [CODE]: message`` and ``hint: hint`` on stderr: the format of
    every error the tools report (the server CLI's)."""
    print(f"{prog}: error [{code}]: {message}", file=sys.stderr)
    print(f"hint: {hint}", file=sys.stderr)


def usage_error(prog: str, message: str, hint: str, code: str = CONFIG_INVALID) -> NoReturn:
    """:func:`print_error` and exit 2, the status of a command-line mistake (``code``:
    CONFIG_INVALID, or a file's)."""
    print_error(prog, code, message, hint)
    raise SystemExit(2)


def describe(exc: BaseException, url: str) -> tuple[str, str, str]:
    """``(code, message, hint)`` of a failure a tool met while running: a refusal by
    the server (its wire code), no session with the server at ``url``
    (:data:`UNREACHABLE`), a BVH that cannot be read (:data:`BVH_INVALID`), a file
    that cannot be read or written (:data:`FILE_INVALID`), a URL or token the client
    refused (:data:`CONFIG_INVALID`); anything else is a bug, re-raised."""
    if isinstance(exc, ProtocolError):
        hint = _WIRE_HINTS.get(exc.code, "see proto/README.md for what the code means")
        return exc.code, exc.message, hint
    if isinstance(exc, BvhError):
        return BVH_INVALID, exc.message, "pass a BVH file (posecast-sim replays .bvh motion)"
    if isinstance(exc, OSError) and exc.filename is not None:
        return FILE_INVALID, f"{exc.filename}: {exc.strerror}", "check the path"
    if isinstance(exc, RecordingError):
        return FILE_INVALID, exc.message, "pass a file posecast-record wrote"
    if isinstance(exc, ConfigInvalidError):  # a URL or token the client refused
        return CONFIG_INVALID, exc.reason, exc.hint
    unreachable = OSError | InvalidURI | InvalidHandshake | ConnectionLostError | TimeoutError
    if isinstance(exc, unreachable):
        return (
            UNREACHABLE,
            f"no session with the server at {url}: {exc!r}",
            "is a server running there? start one with `posecast serve --dev`, or pass --url",
        )
    raise exc


def failure(prog: str, exc: BaseException, url: str) -> NoReturn:
    """Print :func:`describe`'s code, message and hint for ``exc`` and exit 1."""
    print_error(prog, *describe(exc, url))
    raise SystemExit(1)


class Parser(argparse.ArgumentParser):
    """argparse whose refusals (an unknown option, a malformed or missing value) print
    the usage and then :func:`usage_error`'s format."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        hint = f"see `{self.prog} --help` for the options"
        missing = re.fullmatch(r"argument (--?[\w-]+)(?:/[\w-]+)*: expected one argument", message)
        if missing:  # often a value that starts with '-' (a secret can): argparse took it
            hint = f"a value that starts with '-' goes after '=' ({missing[1]}=VALUE); {hint}"
        usage_error(self.prog, message, hint)


def add_server_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--url", help="server WebSocket URL [POSECAST_URL, default ws://127.0.0.1:8765/]"
    )
    auth = parser.add_mutually_exclusive_group()
    auth.add_argument(
        "--secret",
        help="mint dev tokens with this HMAC secret (what `posecast serve --dev` prints) "
        "[POSECAST_TOKEN_SECRET]",
    )
    auth.add_argument("--token", help="use this join token as it is [POSECAST_TOKEN]")
    parser.add_argument("--ttl", type=int, default=3600, help="minted tokens' lifetime, s (3600)")


def resolve_server(
    args: argparse.Namespace, prog: str, env: Mapping[str, str] = os.environ
) -> None:
    """Fill ``url``/``secret``/``token`` from the environment where flags left them out
    (neither anywhere: ``prog``'s :func:`usage_error`)."""
    source = "--url" if args.url else ENV_PREFIX + "URL"
    args.url = args.url or env.get(ENV_PREFIX + "URL") or "ws://127.0.0.1:8765/"
    try:
        args.url = check_url(args.url)  # the client's own check: no connect refuses it later
    except ConfigInvalidError as exc:
        usage_error(prog, f"{source}: {exc.reason}", exc.hint)
    if not args.secret and not args.token:
        args.secret = env.get(ENV_PREFIX + "TOKEN_SECRET") or None
        args.token = env.get(ENV_PREFIX + "TOKEN") or None
    if not args.secret and not args.token:
        usage_error(
            prog,
            "no way to join: neither a token nor a secret to mint one",
            "pass --secret (what `posecast serve --dev` prints) or --token, or set "
            "POSECAST_TOKEN_SECRET or POSECAST_TOKEN",
        )
    problem = secret_problem(args.secret) if args.secret else None
    if problem is not None:  # mint_token's own refusal, as a usage error
        usage_error(
            prog,
            problem,
            "pass the secret the server was started with (`posecast serve --dev` prints it)",
        )
    if not 0 < args.ttl <= MAX_TTL_S:
        usage_error(prog, f"--ttl {args.ttl} is not in (0, {MAX_TTL_S}] seconds", "e.g. 3600")


def check_room(prog: str, flag: str, room: str) -> None:
    """A room name must be a wire id, or the server refuses the join (and no token is minted)."""
    if len(room.encode()) > MAX_ID_BYTES or ID_PATTERN.fullmatch(room) is None:
        usage_error(
            prog,
            f"{flag} {room!r} is not an id: 1 to {MAX_ID_BYTES} of A-Z a-z 0-9 _ . : -",
            "e.g. lobby, match-17",
        )


def token_for(args: argparse.Namespace, room: str, player: str, role: str = "player") -> str:
    if args.token:
        return str(args.token)
    return mint_token(args.secret, room=room, player=player, role=role, ttl_s=args.ttl)


def unique_suffix() -> str:
    return secrets.token_hex(3)


async def connect_patiently(url: str, token: str, tries: int = 8, **options: Any) -> Client:
    """Connect, retrying a refused handshake (HTTP 429 or 503: too many connections
    from this address per minute, or a server still starting) with back-off."""
    delay = 0.25
    for attempt in range(tries):
        try:
            return await connect(url, token, **options)
        except ConnectFailedError as exc:
            if exc.status not in (429, 503) or attempt == tries - 1:
                raise
        await asyncio.sleep(delay)
        delay = min(delay * 2, 8.0)
    raise AssertionError("unreachable")  # pragma: no cover


def stop_on_signals(stop: asyncio.Event) -> None:
    """Set ``stop`` on SIGINT and SIGTERM (where the loop supports signal handlers)."""
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
