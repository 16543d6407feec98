"""What the command-line tools share: server options (flags, then ``POSECAST_*``
environment variables), token minting, signal handling and a patient connect."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import secrets
import signal
from collections.abc import Mapping
from typing import Any

from websockets.exceptions import InvalidStatus

from posecast_client.client import Client, connect
from posecast_client.tokens import mint_token

ENV_PREFIX = "POSECAST_"


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


def resolve_server(args: argparse.Namespace, env: Mapping[str, str] = os.environ) -> None:
    """Fill ``url``/``secret``/``token`` from the environment where flags left them out."""
    args.url = args.url or env.get(ENV_PREFIX + "URL") or "ws://127.0.0.1:8765/"
    if not args.secret and not args.token:
        args.secret = env.get(ENV_PREFIX + "TOKEN_SECRET") or None
        args.token = env.get(ENV_PREFIX + "TOKEN") or None
    if not args.secret and not args.token:
        raise SystemExit("posecast: pass --secret or --token (or set POSECAST_TOKEN_SECRET)")


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
