"""Join tokens: JWTs (RFC 7519, compact JWS) minted by the game backend, verified here.

A token is ``base64url(header) "." base64url(claims) "." base64url(signature)``, as any
JWT library writes it. The header's ``alg`` is one of :data:`~.keys.ALGORITHMS` and must
be the one its key verifies; its ``kid`` names the key in the server's key set (a token
without one is checked with the set's only key, when it holds exactly one). Claims:

=========  ========  ============================================================
claim      type      meaning
=========  ========  ============================================================
``room``   str       the room this token joins
``player`` str       the player id the connection takes (server-unique)
``role``   str       ``player`` | ``spectator`` | ``backend``
``rooms``  [str]     further rooms a ``backend`` may watch (optional, backends only)
``iat``    int       issued at, Unix seconds
``exp``    int       expires at, Unix seconds
``jti``    str       unique token id (replay protection after ``bye``)
``nbf``    int       not before, Unix seconds (optional; standard, checked if present)
=========  ========  ============================================================

Signature and structure are PyJWT's (with ``algorithms`` pinned to the key's one);
the times are checked here against the ``now`` passed in, so the clock stays the
caller's. Every refusal carries a stable ``reason`` (:data:`REASONS`), counted in
``/metrics``, and a message that never quotes the token.

The pre-JWT format (``base64url(claims) "." base64url(HMAC)``, one dot) is refused
with ``old_format``, naming the change (docs/operations.md, "Upgrading").
"""

from __future__ import annotations

import base64
import binascii
import heapq
import json
import secrets
from dataclasses import dataclass, field
from typing import Any

import jwt

from posecast.errors import TokenExpiredError, UnauthenticatedError
from posecast.online.auth.keys import ALGORITHMS, KID_PATTERN, Key, KeySet, SigningKey
from posecast.online.protocol.fields import ID_PATTERN
from posecast.online.protocol.messages import MAX_ID_BYTES, ROLES

MAX_TOKEN_CHARS = 4096
MAX_TTL_S = 7 * 24 * 3600  # the minting CLI refuses longer-lived tokens
# Why a token was refused: the label of posecast_token_refusals_total.
REASONS = (
    "missing",  # no token at all
    "old_format",  # the pre-JWT posecast format
    "malformed",  # not a compact JWS, or its header is not base64url JSON
    "alg_refused",  # alg not allow-listed (none, RS256, HS512, ...)
    "alg_mismatch",  # alg allow-listed, but not the one its key verifies
    "unknown_kid",  # kid not in the key set (or none, with several keys)
    "bad_signature",  # wrong key, tampered header or claims
    "bad_claims",  # a claim missing or of the wrong type or value
    "expired",  # TOKEN_EXPIRED: exp passed (with the leeway)
    "not_yet_valid",  # TOKEN_EXPIRED: iat or nbf in the future (past the leeway)
    "replayed",  # its session ended with bye or a kick
)


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


def _signing_key(key: bytes | str | SigningKey) -> SigningKey:
    if isinstance(key, SigningKey):
        return key
    if not key:
        raise ValueError("the token secret must not be empty")
    return SigningKey("HS256", key.encode("utf-8") if isinstance(key, str) else key)


def mint(
    key: bytes | str | SigningKey,
    *,
    room: str,
    player: str,
    role: str = "player",
    ttl_s: int = 3600,
    now: float,
    rooms: tuple[str, ...] = (),
    jti: str | None = None,
) -> str:
    """A JWT for ``player`` in ``room`` valid for ``ttl_s`` seconds from ``now``,
    signed with ``key``: an HS256 secret (no ``kid``) or a :class:`SigningKey`."""
    sk = _signing_key(key)
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
        "room": room,
        "player": player,
        "role": role,
        "iat": iat,
        "exp": iat + ttl_s,
        "jti": jti or secrets.token_urlsafe(12),
    }
    if rooms:
        claims["rooms"] = list(rooms)
    headers = {"kid": sk.kid} if sk.kid is not None else None
    return jwt.encode(claims, sk.material, algorithm=sk.alg, headers=headers)


def _refused(reason: str, message: str) -> UnauthenticatedError:
    return UnauthenticatedError(message, reason=reason, field="token")


def _shown(value: object) -> str:
    """A header value fit to quote in an error: a short id as is, anything else not."""
    if isinstance(value, str) and KID_PATTERN.fullmatch(value):
        return repr(value)
    return "(not shown: not a short id)"


def _header(token: str) -> dict[str, Any]:
    """The JOSE header, read only to pick the key: PyJWT then reads the whole token
    again, strictly, and verifies it (this saves its strict read of the header twice,
    a third of a check's cost)."""
    part = token.split(".", 1)[0]
    try:
        header = json.loads(base64.urlsafe_b64decode(part + "=" * (-len(part) % 4)))
    except (ValueError, binascii.Error, RecursionError):
        raise _refused("malformed", "token header is not base64url JSON") from None
    if not isinstance(header, dict):
        raise _refused("malformed", "token header is not a JSON object")
    return header


def _pick_key(keys: KeySet, token: str) -> Key:
    """The key that must verify ``token``, from its header, before any signature
    check: refused here are a non-JWT, an alg off the list, an unknown kid, and an
    alg that is not the one its key verifies (algorithm confusion)."""
    if not token:
        raise _refused("missing", "no token: hello.token must be a JWT from the game backend")
    if len(token) > MAX_TOKEN_CHARS:
        raise _refused("malformed", f"token is longer than {MAX_TOKEN_CHARS} characters")
    if token.count(".") == 1:
        raise _refused(
            "old_format",
            "token is in posecast's pre-JWT format (claims.mac): servers now take JWTs"
            " (RFC 7519); mint with a JWT library or an SDK of this release"
            " (docs/operations.md, Upgrading)",
        )
    if token.count(".") != 2:
        raise _refused("malformed", "token is not a JWT (header.claims.signature)")
    header = _header(token)
    alg = header.get("alg")
    if alg not in ALGORITHMS:
        raise _refused(
            "alg_refused",
            f"token alg {_shown(alg)} is not accepted: one of {', '.join(ALGORITHMS)}",
        )
    if "crit" in header or "b64" in header:  # extensions we do not implement (RFC 7515 4.1.11)
        raise _refused("malformed", "token header asks for JWS extensions (crit, b64)")
    kid = header.get("kid")
    if kid is not None and not isinstance(kid, str):
        raise _refused("malformed", "token kid is not a string")
    if kid is None:
        if len(keys) != 1:
            raise _refused("unknown_kid", f"token has no kid and the server holds {len(keys)} keys")
        key = next(iter(keys.keys.values()))
    else:
        found = keys.keys.get(kid) if isinstance(kid, str) else None
        if found is None:
            raise _refused("unknown_kid", f"token kid {_shown(kid)} is unknown to this server")
        key = found
    if alg != key.alg:
        raise _refused(
            "alg_mismatch",
            f"token alg {alg!r} is not its key's: key {key.kid!r} verifies {key.alg} only",
        )
    return key


def verify(keys: KeySet | bytes | str, token: str, *, now: float, leeway_s: float = 0.0) -> Claims:
    """The claims of a token whose signature verifies and that is valid at ``now``.

    ``keys``: the server's key set, or one HS256 secret (tests, tools).

    Raises:
        UnauthenticatedError: malformed, forged, of an unknown key or with bad claims.
        TokenExpiredError: genuine but expired (or not valid yet), past ``leeway_s``.
    """
    if not isinstance(keys, KeySet):
        keys = KeySet.from_secret(keys)
    key = _pick_key(keys, token)
    try:
        c = jwt.decode(
            token,
            key.material,
            algorithms=[key.alg],
            # The times are checked below against the caller's clock, not PyJWT's.
            # aud, iss and sub are the backend's own business (posecast's are room,
            # player and role): present or not, they are not checked.
            options={
                "verify_exp": False,
                "verify_iat": False,
                "verify_nbf": False,
                "verify_aud": False,
                "verify_iss": False,
                "verify_sub": False,
                "verify_jti": False,
            },
        )
    except jwt.InvalidSignatureError:
        raise _refused("bad_signature", "token signature does not verify") from None
    except jwt.PyJWTError:
        raise _refused("malformed", "token claims are not a base64url JSON object") from None
    claims = _claims(c)
    nbf = c.get("nbf", claims.iat)
    if type(nbf) is not int:
        raise _refused("bad_claims", "token claim nbf is not an integer")
    if now + leeway_s < max(claims.iat, nbf):
        raise TokenExpiredError("token is not valid yet", reason="not_yet_valid", field="token")
    if now - leeway_s >= claims.exp:
        raise TokenExpiredError("token has expired", reason="expired", field="token")
    return claims


def _claims(c: object) -> Claims:
    def bad(what: str) -> UnauthenticatedError:
        return _refused("bad_claims", f"token claim {what}")

    if not isinstance(c, dict):
        raise bad("set is not a JSON object")
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
        raise bad(f"role {_shown(c['role'])} is unknown")
    rooms = c.get("rooms", [])
    if not isinstance(rooms, list) or not all(isinstance(r, str) and r for r in rooms):
        raise bad("rooms is not a list of strings")
    if rooms and c["role"] != "backend":
        raise bad("rooms is only for backends")
    return Claims(c["room"], c["player"], c["role"], c["iat"], c["exp"], c["jti"], tuple(rooms))


@dataclass
class Verifier:
    """The server's token check: the current key set (swapped whole on a reload, so a
    ``hello`` sees the old set or the new one, never a mix) and the leeway."""

    keys: KeySet
    leeway_s: float = 0.0

    def verify(self, token: str, now: float) -> Claims:
        return verify(self.keys, token, now=now, leeway_s=self.leeway_s)


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
            raise UnauthenticatedError(
                "token was already used by a session that ended", reason="replayed"
            )

    def __len__(self) -> int:
        return len(self._exp)

    def _purge(self, now: float) -> None:
        while self._heap and self._heap[0][0] <= now:
            _, jti = heapq.heappop(self._heap)
            self._exp.pop(jti, None)


def new_secret() -> str:
    """A random secret for ``--dev`` (256 bits, URL-safe text: 43 characters)."""
    return secrets.token_urlsafe(32)
