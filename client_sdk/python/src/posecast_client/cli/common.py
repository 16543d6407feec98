"""What the command-line tools share: server options (flags, then ``POSECAST_*``
environment variables), token minting, signal handling, a patient connect, and the
error format of a command-line mistake (``PROG: error [CONFIG_INVALID]: ...`` and a
``hint:`` line, exit 2: the server CLI's format)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import secrets
import signal
import sys
from collections.abc import Mapping
from typing import Any, NoReturn

from websockets.exceptions import InvalidStatus

from posecast_client.client import Client, connect
from posecast_client.tokens import mint_token

ENV_PREFIX = "POSECAST_"
CONFIG_INVALID = "CONFIG_INVALID"  # the server's code for a bad configuration value


def usage_error(prog: str, message: str, hint: str) -> NoReturn:
    """Print ``prog: error [CONFIG_INVALID]: message`` and ``hint: hint`` on stderr and
    exit 2, the status of a command-line mistake."""
    print(f"{prog}: error [{CONFIG_INVALID}]: {message}", file=sys.stderr)
    print(f"hint: {hint}", file=sys.stderr)
    raise SystemExit(2)


class Parser(argparse.ArgumentParser):
    """argparse whose refusals (an unknown option, a malformed or missing value) print
    the usage and then :func:`usage_error`'s format."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        usage_error(self.prog, message, f"see `{self.prog} --help` for the options")


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
    args.url = args.url or env.get(ENV_PREFIX + "URL") or "ws://127.0.0.1:8765/"
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
        except InvalidStatus as exc:
            if exc.response.status_code not in (429, 503) or attempt == tries - 1:
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
