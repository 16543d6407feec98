"""Minting join tokens, for development and tests.

In production the game backend mints tokens and keeps the key; a client only
passes its token on. A token is a JWT (RFC 7519, compact JWS), as any JWT library
writes it, signed with one of the server's keys:

* ``HS256`` with a shared secret: the server's ``POSECAST_TOKEN_SECRET`` (a
  ``posecast serve --dev`` server prints its own) or an ``oct`` key of its key set;
* ``ES256`` or ``EdDSA`` with a private key (a JWK, as ``posecast keygen`` writes it),
  whose public half is in the server's key set (needs ``posecast-client[keys]``).

The header names the key (``kid``) when the server holds several. Claims: ``room``,
``player``, ``role``, ``iat`` and ``exp`` (Unix seconds), ``jti`` (a unique id) and,
for backends only, ``rooms`` (proto/README.md, Join tokens).
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Mapping
from typing import Any

import jwt

from posecast_client.codec import ID_PATTERN as _ID
from posecast_client.protocol import MAX_ID_BYTES, ROLES

MAX_TTL_S = 7 * 24 * 3600  # what the server's minting tool allows
MIN_SECRET_CHARS = 32  # the server refuses shorter secrets (posecast.online.config)
ALGORITHMS = ("HS256", "ES256", "EdDSA")  # what a server verifies, each with its kind of key
_KINDS = {("oct", None): "HS256", ("EC", "P-256"): "ES256", ("OKP", "Ed25519"): "EdDSA"}


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


def _signing(key: str | bytes | Mapping[str, Any]) -> tuple[str, Any, str | None]:
    """``(alg, key material, kid)`` of a secret or a private JWK."""
    if isinstance(key, str | bytes):
        problem = secret_problem(key)
        if problem is not None:
            raise ValueError(problem)
        return "HS256", key.encode("utf-8") if isinstance(key, str) else key, None
    kind = (key.get("kty"), key.get("crv") if key.get("kty") != "oct" else None)
    alg = _KINDS.get(kind)  # type: ignore[arg-type]
    if alg is None:
        raise ValueError(f"a {kind[0]} {kind[1] or ''} key: posecast verifies {_KINDS}")
    if alg != "HS256" and "d" not in key:
        raise ValueError("this is a public key: minting needs the private key (its d)")
    try:
        material = jwt.PyJWK(dict(key), algorithm=alg).key
    except jwt.PyJWTError as exc:  # its message names what is missing, never the key
        raise ValueError(f"not a valid {alg} key ({type(exc).__name__})") from None
    if alg == "HS256" and len(material) < MIN_SECRET_CHARS:
        raise ValueError(f"an HS256 key must be at least {MIN_SECRET_CHARS} bytes")
    kid = key.get("kid")
    return alg, material, kid if isinstance(kid, str) else None


def mint_token(
    key: str | bytes | Mapping[str, Any],
    *,
    room: str,
    player: str,
    role: str = "player",
    ttl_s: int = 3600,
    rooms: tuple[str, ...] = (),
    now: float | None = None,
    jti: str | None = None,
    kid: str | None = None,
    alg: str | None = None,
) -> str:
    """A join token (a JWT) for ``player`` in ``room``, valid ``ttl_s`` seconds from ``now``.

    Args:
        key: the server's token secret (``POSECAST_TOKEN_SECRET``; text is UTF-8),
            signing HS256; or a private JWK (a dict, as ``posecast keygen`` writes
            it) signing ES256 or EdDSA, or an ``oct`` JWK signing HS256. A secret
            shorter than any server takes (:data:`MIN_SECRET_CHARS` characters) is
            refused: no server would verify the token.
        role: ``player``, ``spectator`` or ``backend``.
        rooms: further rooms a backend may watch.
        now: Unix time of issue (default: the wall clock).
        jti: the token's unique id (default: random).
        kid: the key id written in the header (default: the JWK's ``kid``; none for
            a secret, which a server holding one key takes).
        alg: the algorithm, checked against the key's (default: the key's).
    """
    key_alg, material, key_kid = _signing(key)
    if alg is not None and alg != key_alg:
        raise ValueError(f"alg {alg!r} does not fit the key, which signs {key_alg}")
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
        "room": room,
        "player": player,
        "role": role,
        "iat": iat,
        "exp": iat + ttl_s,
        "jti": jti or secrets.token_urlsafe(12),
    }
    if rooms:
        claims["rooms"] = list(rooms)
    kid = kid if kid is not None else key_kid
    headers = {"kid": kid} if kid else None
    return jwt.encode(claims, material, algorithm=key_alg, headers=headers)
