"""Signed join tokens: minted by the game backend, verified by the server.

Format (compact, URL-safe, no padding)::

    base64url(JSON claims) "." base64url(HMAC-SHA256(secret, first part))

The MAC covers the exact claim bytes that were sent, so the server never has to
re-serialise JSON to check it. Claims:

=======  ========  ==============================================================
claim    type      meaning
=======  ========  ==============================================================
``v``    int       token format version (1)
``room`` str       the room this token joins
``player`` str     the player id the connection takes (server-unique)
``role`` str       ``player`` | ``spectator`` | ``backend``
``rooms`` [str]    further rooms a ``backend`` may watch (optional, backends only)
``iat``  int       issued at, Unix seconds
``exp``  int       expires at, Unix seconds
``jti``  str       unique token id (replay protection after ``bye``)
=======  ========  ==============================================================

Pure functions plus one bounded in-memory set; the clock is always passed in.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import heapq
import hmac
import json
import secrets
from dataclasses import dataclass, field
from typing import Any

from posecast.errors import TokenExpiredError, UnauthenticatedError
from posecast.online.protocol.fields import ID_PATTERN
from posecast.online.protocol.messages import MAX_ID_BYTES, ROLES

TOKEN_VERSION = 1
MAX_TOKEN_CHARS = 4096
MAX_TTL_S = 7 * 24 * 3600  # the minting CLI refuses longer-lived tokens


def _is_id(value: object) -> bool:
    """A room or player claim must be a wire `id` (proto/README.md, Messages): the player
    id goes out as is in welcome, presence and pose, where every client's decoder checks it."""
    return (
        isinstance(value, str)
        and len(value.encode()) <= MAX_ID_BYTES
        and ID_PATTERN.fullmatch(value) is not None
    )


@dataclass(frozen=True, slots=True)
class Claims:
    """What a verified token allows. ``rooms`` is every room this token may see:
    ``room`` first, then a backend's extra rooms."""

    room: str
    player: str
    role: str
    iat: int
    exp: int
    jti: str
    rooms: tuple[str, ...] = field(default=())

    def allows_room(self, room: str) -> bool:
        return room == self.room or room in self.rooms


def _b64e(raw: bytes) -> str:
    return base64.urlsafe_b64encode(raw).rstrip(b"=").decode("ascii")


def _b64d(text: str) -> bytes:
    return base64.urlsafe_b64decode(text + "=" * (-len(text) % 4))


def _mac(secret: bytes, payload: str) -> bytes:
    return hmac.new(secret, payload.encode("ascii"), hashlib.sha256).digest()


def mint(
    secret: bytes,
    *,
    room: str,
    player: str,
    role: str = "player",
    ttl_s: int = 3600,
    now: float,
    rooms: tuple[str, ...] = (),
    jti: str | None = None,
) -> str:
    """A token for ``player`` in ``room`` valid for ``ttl_s`` seconds from ``now``."""
    if not secret:
        raise ValueError("the token secret must not be empty")
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, not {role!r}")
    if rooms and role != "backend":
        raise ValueError("only a backend token may list extra rooms")
    if not 0 < ttl_s <= MAX_TTL_S:
        raise ValueError(f"ttl_s must be in (0, {MAX_TTL_S}]")
    for what, value in (("room", room), ("player", player), *(("rooms", r) for r in rooms)):
        if not _is_id(value):
            raise ValueError(
                f"{what} {value!r} is not an id: 1 to {MAX_ID_BYTES} of A-Z a-z 0-9 _ . : -"
            )
    iat = int(now)
    claims: dict[str, Any] = {
        "v": TOKEN_VERSION,
        "room": room,
        "player": player,
        "role": role,
        "iat": iat,
        "exp": iat + ttl_s,
        "jti": jti or secrets.token_urlsafe(12),
    }
    if rooms:
        claims["rooms"] = list(rooms)
    payload = _b64e(json.dumps(claims, separators=(",", ":"), sort_keys=True).encode())
    return payload + "." + _b64e(_mac(secret, payload))


def verify(secret: bytes, token: str, *, now: float, leeway_s: float = 0.0) -> Claims:
    """The claims of a token whose MAC verifies and that is valid at ``now``.

    Raises:
        UnauthenticatedError: malformed, forged or with bad claims.
        TokenExpiredError: genuine but expired (or issued in the future, past leeway).
    """
    if len(token) > MAX_TOKEN_CHARS or token.count(".") != 1:
        raise UnauthenticatedError("token is not <claims>.<mac>", field="token")
    payload, mac_text = token.split(".")
    try:
        mac = _b64d(mac_text)
        raw = _b64d(payload)
    except (binascii.Error, ValueError):
        raise UnauthenticatedError("token is not base64url", field="token") from None
    # Constant-time: the comparison takes as long whatever prefix matches.
    if not hmac.compare_digest(mac, _mac(secret, payload)):
        raise UnauthenticatedError("token signature does not verify", field="token")
    try:
        c = json.loads(raw)
    except (UnicodeDecodeError, ValueError):
        raise UnauthenticatedError("token claims are not JSON", field="token") from None
    claims = _claims(c)
    if now + leeway_s < claims.iat:
        raise TokenExpiredError("token is not valid yet", field="token")
    if now - leeway_s >= claims.exp:
        raise TokenExpiredError("token has expired", field="token")
    return claims


def _claims(c: object) -> Claims:
    def bad(what: str) -> UnauthenticatedError:
        return UnauthenticatedError(f"token claim {what}", field="token")

    if not isinstance(c, dict) or c.get("v") != TOKEN_VERSION:
        raise bad("v is missing or not 1")
    for key in ("room", "player", "role", "jti"):
        if not isinstance(c.get(key), str) or not c[key]:
            raise bad(f"{key} is missing or not a string")
    for key in ("room", "player"):
        if not _is_id(c[key]):
            raise bad(f"{key} is not an id (1 to {MAX_ID_BYTES} of A-Z a-z 0-9 _ . : -)")
    for key in ("iat", "exp"):
        if type(c.get(key)) is not int:
            raise bad(f"{key} is missing or not an integer")
    if c["role"] not in ROLES:
        raise bad(f"role {c['role']!r} is unknown")
    rooms = c.get("rooms", [])
    if not isinstance(rooms, list) or not all(isinstance(r, str) and r for r in rooms):
        raise bad("rooms is not a list of strings")
    if rooms and c["role"] != "backend":
        raise bad("rooms is only for backends")
    return Claims(c["room"], c["player"], c["role"], c["iat"], c["exp"], c["jti"], tuple(rooms))


@dataclass
class ReplayGuard:
    """Token ids of sessions that ended (``bye``, kick), remembered until they expire.

    "Expire" is as :func:`verify` sees it: ``exp`` plus the ``leeway_s`` it allows, so a
    burned token is never accepted again in the leeway after its ``exp``.
    Bounded: past ``capacity`` entries, the one expiring soonest is forgotten first
    (it is the one whose replay window is shortest). Memory is O(capacity).
    """

    capacity: int = 100_000
    leeway_s: float = 0.0
    _exp: dict[str, float] = field(default_factory=dict)
    _heap: list[tuple[float, str]] = field(default_factory=list)

    def end(self, claims: Claims, now: float) -> None:
        """Burn ``claims.jti``: later ``hello``s with it are refused until it expires."""
        self._purge(now)
        until = claims.exp + self.leeway_s
        if claims.jti in self._exp or until <= now:
            return
        while len(self._exp) >= self.capacity:
            _, old = heapq.heappop(self._heap)
            self._exp.pop(old, None)
        self._exp[claims.jti] = until
        heapq.heappush(self._heap, (until, claims.jti))

    def check(self, claims: Claims, now: float) -> None:
        """Raise UNAUTHENTICATED if ``claims.jti`` belongs to an ended session."""
        self._purge(now)
        if claims.jti in self._exp:
            raise UnauthenticatedError("token was already used by a session that ended")

    def __len__(self) -> int:
        return len(self._exp)

    def _purge(self, now: float) -> None:
        while self._heap and self._heap[0][0] <= now:
            _, jti = heapq.heappop(self._heap)
            self._exp.pop(jti, None)


def new_secret() -> str:
    """A random secret for ``--dev`` (256 bits, URL-safe text)."""
    return secrets.token_urlsafe(32)
