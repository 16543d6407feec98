"""Minting join tokens, for development and tests.

In production the game backend mints tokens and keeps the secret; a client only
passes its token on. For a ``posecast serve --dev`` server (which prints its secret)
and for simulators, this mints tokens in the server's format::

    base64url(JSON claims, compact, sorted keys) "." base64url(HMAC-SHA256(secret, first part))

without padding. Claims: ``v`` (1), ``room``, ``player``, ``role``, ``iat`` and
``exp`` (Unix seconds), ``jti`` (a unique id) and, for backends only, ``rooms``.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import secrets
import time
from typing import Any

from posecast_client.codec import ID_PATTERN as _ID
from posecast_client.protocol import MAX_ID_BYTES, ROLES

MAX_TTL_S = 7 * 24 * 3600  # what the server's minting tool allows
MIN_SECRET_CHARS = 16  # the server refuses shorter secrets (posecast.online.config)


def secret_problem(secret: str | bytes) -> str | None:
    """Why no server verifies tokens minted with ``secret``, or None if one may.

    A server's secret is text of at least :data:`MIN_SECRET_CHARS` characters (its
    ``POSECAST_TOKEN_SECRET``, keyed as UTF-8), so the length counts characters as the
    server does: of ``secret``, or of the text whose UTF-8 bytes ``secret`` is."""
    if isinstance(secret, bytes):
        try:
            secret = secret.decode("utf-8")
        except UnicodeDecodeError:
            return "the secret is not UTF-8 text, and a server's secret is text"
    if len(secret) < MIN_SECRET_CHARS:
        return (
            f"the secret has {len(secret)} characters; a server takes none under "
            f"{MIN_SECRET_CHARS}, so no server verifies tokens minted with it"
        )
    return None


def _b64(raw: bytes) -> str:
    return base64.urlsafe_b64encode(raw).rstrip(b"=").decode("ascii")


def mint_token(
    secret: str | bytes,
    *,
    room: str,
    player: str,
    role: str = "player",
    ttl_s: int = 3600,
    rooms: tuple[str, ...] = (),
    now: float | None = None,
    jti: str | None = None,
) -> str:
    """A join token for ``player`` in ``room``, valid ``ttl_s`` seconds from ``now``.

    Args:
        secret: the server's token secret (``POSECAST_TOKEN_SECRET``); text is UTF-8.
            One shorter than any server takes (:data:`MIN_SECRET_CHARS` characters)
            is refused: no server would verify the token.
        role: ``player``, ``spectator`` or ``backend``.
        rooms: further rooms a backend may watch.
        now: Unix time of issue (default: the wall clock).
        jti: the token's unique id (default: random).
    """
    problem = secret_problem(secret)
    if problem is not None:
        raise ValueError(problem)
    key = secret.encode("utf-8") if isinstance(secret, str) else secret
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, not {role!r}")
    if rooms and role != "backend":
        raise ValueError("only a backend token may list extra rooms")
    if not 0 < ttl_s <= MAX_TTL_S:
        raise ValueError(f"ttl_s must be in (0, {MAX_TTL_S}]")
    for what, value in (("room", room), ("player", player), *(("rooms", r) for r in rooms)):
        # The server refuses a token whose room or player is not a wire id (proto/README.md).
        if len(value.encode()) > MAX_ID_BYTES or _ID.fullmatch(value) is None:
            raise ValueError(
                f"{what} {value!r} is not an id: 1 to {MAX_ID_BYTES} of A-Z a-z 0-9 _ . : -"
            )
    iat = int(time.time() if now is None else now)
    claims: dict[str, Any] = {
        "v": 1,
        "room": room,
        "player": player,
        "role": role,
        "iat": iat,
        "exp": iat + ttl_s,
        "jti": jti or secrets.token_urlsafe(12),
    }
    if rooms:
        claims["rooms"] = list(rooms)
    payload = _b64(json.dumps(claims, separators=(",", ":"), sort_keys=True).encode())
    mac = hmac.new(key, payload.encode("ascii"), hashlib.sha256).digest()
    return payload + "." + _b64(mac)
