"""Join tokens (posecast.online.auth.tokens): JWTs minted and verified, every refusal
with its code and reason, expiry and replay."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
from collections.abc import Callable

import jwt
import pytest

from posecast.errors import TokenExpiredError, UnauthenticatedError
from posecast.online.auth.keys import KeySet, SigningKey, generate, parse_key_set
from posecast.online.auth.tokens import REASONS, Claims, ReplayGuard, mint, verify

SECRET = b"k" * 32
NOW = 1_700_000_000.0
CLAIMS = {"room": "lobby", "player": "p1", "role": "player", "iat": int(NOW),
          "exp": int(NOW) + 60, "jti": "j"}  # fmt: skip


def _token(**kw: object) -> str:
    args: dict[str, object] = {"room": "lobby", "player": "p1", "role": "player", "now": NOW}
    args.update(kw)
    return mint(SECRET, **args)  # type: ignore[arg-type]


def _b64(raw: bytes) -> str:
    return base64.urlsafe_b64encode(raw).rstrip(b"=").decode()


def _jws(header: dict[str, object], claims: dict[str, object], key: bytes = SECRET) -> str:
    """A compact JWS built by hand (HMAC-SHA256 over whatever header it is given)."""
    first = _b64(json.dumps(header).encode()) + "." + _b64(json.dumps(claims).encode())
    return first + "." + _b64(hmac.new(key, first.encode(), hashlib.sha256).digest())


def _refusal(keys: KeySet | bytes, token: str, now: float = NOW) -> tuple[str, str, str]:
    """(code, reason, message) of the refusal of ``token``; fails if it verifies."""
    with pytest.raises((UnauthenticatedError, TokenExpiredError)) as info:
        verify(keys, token, now=now, leeway_s=1.0)
    exc = info.value
    assert isinstance(exc, UnauthenticatedError | TokenExpiredError)
    assert exc.reason in REASONS
    if len(token) > 8:  # never quotes the token, nor any of its three parts
        assert all(p not in exc.message for p in token.split(".") if len(p) > 8), exc.message
    return exc.code, exc.reason, exc.message


def test_mint_then_verify_round_trips_every_claim() -> None:
    token = _token(ttl_s=60, jti="abc")
    c = verify(SECRET, token, now=NOW + 1)
    assert (c.room, c.player, c.role, c.jti) == ("lobby", "p1", "player", "abc")
    assert (c.iat, c.exp) == (int(NOW), int(NOW) + 60)
    # A standard JWT: any JWT library reads it.
    assert jwt.decode(token, SECRET, algorithms=["HS256"], options={"verify_exp": False}) == {
        "room": "lobby", "player": "p1", "role": "player", "iat": int(NOW),
        "exp": int(NOW) + 60, "jti": "abc",
    }  # fmt: skip


def test_tokens_are_compact_urlsafe_and_unique() -> None:
    a, b = _token(), _token()
    assert a != b  # a fresh jti each time
    assert a.count(".") == 2 and "=" not in a and "+" not in a and "/" not in a


def test_backend_token_lists_rooms() -> None:
    c = verify(SECRET, _token(role="backend", rooms=("a", "b")), now=NOW)
    assert c.rooms == ("a", "b")
    assert c.allows_room("lobby") and c.allows_room("b") and not c.allows_room("c")


def test_only_backends_may_list_rooms() -> None:
    with pytest.raises(ValueError, match="backend"):
        _token(role="player", rooms=("a",))


# --- every refusal, with its code and reason -----------------------------------------

ES_PRIVATE, ES_PUBLIC = generate("ES256", "es")
ED_PRIVATE, ED_PUBLIC = generate("EdDSA", "ed")
HS_KEY = {"kty": "oct", "kid": "hs", "k": _b64(SECRET)}
KEYS = parse_key_set(json.dumps({"keys": [ES_PUBLIC, ED_PUBLIC, HS_KEY]}), "test")
ES = SigningKey.from_jwk(ES_PRIVATE)
ED = SigningKey.from_jwk(ED_PRIVATE)
HS = SigningKey("HS256", SECRET, "hs")


def _es_public_pem() -> bytes:
    from cryptography.hazmat.primitives import serialization

    return KEYS.keys["es"].material.public_bytes(  # type: ignore[no-any-return]
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )


def _reclaim(token: str, **changes: object) -> str:
    """``token`` with its claims edited and its header and signature kept."""
    header, claims, sig = token.split(".")
    c = json.loads(base64.urlsafe_b64decode(claims + "=" * (-len(claims) % 4)))
    c.update(changes)
    return header + "." + _b64(json.dumps(c, separators=(",", ":")).encode()) + "." + sig


def _flip_last(token: str) -> str:
    """``token`` with a byte of its signature changed (its first character: every bit of
    it counts, unlike the last one's padding bits)."""
    head, sig = token.rsplit(".", 1)
    return head + "." + ("B" if sig[0] == "A" else "A") + sig[1:]


def _without(claim: str) -> dict[str, object]:
    return {k: v for k, v in CLAIMS.items() if k != claim}


REFUSED: dict[str, tuple[Callable[[], str], str, str]] = {
    # name: (token, code, reason)
    "no token": (lambda: "", "UNAUTHENTICATED", "missing"),
    "old format": (
        lambda: _b64(json.dumps({"v": 1, **CLAIMS}).encode()) + "." + _b64(b"m" * 32),
        "UNAUTHENTICATED", "old_format",
    ),
    "garbage": (lambda: "x" * 4000, "UNAUTHENTICATED", "malformed"),
    "too long": (lambda: "a." * 2049, "UNAUTHENTICATED", "malformed"),
    "four parts": (lambda: mint(HS, room="r", player="p", now=NOW) + ".x",
                   "UNAUTHENTICATED", "malformed"),
    "header not JSON": (lambda: "!!!.e30.e30", "UNAUTHENTICATED", "malformed"),
    "alg none": (
        lambda: _b64(b'{"alg":"none","kid":"hs"}') + "." + _b64(json.dumps(CLAIMS).encode()) + ".",
        "UNAUTHENTICATED", "alg_refused",
    ),
    "alg None spelt otherwise": (lambda: _jws({"alg": "nOnE", "kid": "hs"}, CLAIMS),
                                 "UNAUTHENTICATED", "alg_refused"),
    "alg HS512": (lambda: jwt.encode(CLAIMS, SECRET * 2, algorithm="HS512", headers={"kid": "hs"}),
                  "UNAUTHENTICATED", "alg_refused"),
    "no alg": (lambda: _jws({"kid": "hs"}, CLAIMS), "UNAUTHENTICATED", "alg_refused"),
    # Algorithm confusion: HS256 keyed with the ES256 public key (which is public).
    "HS256 with the public key as secret": (
        lambda: _jws({"alg": "HS256", "kid": "es"}, CLAIMS, _es_public_pem()),
        "UNAUTHENTICATED", "alg_mismatch",
    ),
    "EdDSA token naming the ES256 key": (
        lambda: mint(SigningKey("EdDSA", ED.material, "es"), room="r", player="p", now=NOW),
        "UNAUTHENTICATED", "alg_mismatch",
    ),
    "unknown kid": (lambda: mint(SigningKey("HS256", SECRET, "gone"), room="r", player="p",
                                 now=NOW), "UNAUTHENTICATED", "unknown_kid"),
    "no kid, several keys": (lambda: mint(SECRET, room="r", player="p", now=NOW),
                             "UNAUTHENTICATED", "unknown_kid"),
    "kid not a string": (lambda: _jws({"alg": "HS256", "kid": 7}, CLAIMS),
                         "UNAUTHENTICATED", "malformed"),  # PyJWT: a kid is a string
    "wrong HS256 secret": (lambda: mint(SigningKey("HS256", b"w" * 32, "hs"), room="r",
                                        player="p", now=NOW), "UNAUTHENTICATED", "bad_signature"),
    "wrong ES256 key": (lambda: mint(SigningKey.from_jwk(generate("ES256", "es")[0]), room="r",
                                     player="p", now=NOW), "UNAUTHENTICATED", "bad_signature"),
    "wrong EdDSA key": (lambda: mint(SigningKey.from_jwk(generate("EdDSA", "ed")[0]), room="r",
                                     player="p", now=NOW), "UNAUTHENTICATED", "bad_signature"),
    "tampered ES256 claims": (
        lambda: _reclaim(mint(ES, room="r", player="p", role="spectator", now=NOW), role="player"),
        "UNAUTHENTICATED", "bad_signature",
    ),
    "tampered EdDSA claims": (lambda: _reclaim(mint(ED, room="r", player="p", now=NOW), room="x"),
                              "UNAUTHENTICATED", "bad_signature"),
    "signature changed": (lambda: _flip_last(mint(HS, room="r", player="p", now=NOW)),
                          "UNAUTHENTICATED", "bad_signature"),
    "signature cut": (lambda: mint(HS, room="r", player="p", now=NOW)[:-2],
                      "UNAUTHENTICATED", "malformed"),  # 41 characters: not base64url
    "crit header": (lambda: _jws({"alg": "HS256", "kid": "hs", "crit": ["x"], "x": 1}, CLAIMS),
                    "UNAUTHENTICATED", "malformed"),
    "claims not an object": (lambda: jwt.api_jws.encode(b"[1]", SECRET, "HS256", {"kid": "hs"}),
                             "UNAUTHENTICATED", "malformed"),
    "missing player": (lambda: _jws({"alg": "HS256", "kid": "hs"}, _without("player")),
                       "UNAUTHENTICATED", "bad_claims"),
    "missing exp": (lambda: _jws({"alg": "HS256", "kid": "hs"}, _without("exp")),
                    "UNAUTHENTICATED", "bad_claims"),
    "missing jti": (lambda: _jws({"alg": "HS256", "kid": "hs"}, _without("jti")),
                    "UNAUTHENTICATED", "bad_claims"),
    "iat a string": (lambda: _jws({"alg": "HS256", "kid": "hs"}, {**CLAIMS, "iat": "0"}),
                     "UNAUTHENTICATED", "bad_claims"),
    "unknown role": (lambda: _jws({"alg": "HS256", "kid": "hs"}, {**CLAIMS, "role": "admin"}),
                     "UNAUTHENTICATED", "bad_claims"),
    "expired": (lambda: mint(ES, room="r", player="p", now=NOW - 120, ttl_s=60),
                "TOKEN_EXPIRED", "expired"),
    "not yet valid (iat)": (lambda: mint(ED, room="r", player="p", now=NOW + 60),
                            "TOKEN_EXPIRED", "not_yet_valid"),
    "not yet valid (nbf)": (
        lambda: _jws({"alg": "HS256", "kid": "hs"}, {**CLAIMS, "nbf": int(NOW) + 60}),
        "TOKEN_EXPIRED", "not_yet_valid",
    ),
}  # fmt: skip


@pytest.mark.parametrize("name", REFUSED)
def test_every_bad_token_is_refused_with_its_code_and_reason(name: str) -> None:
    make, code, reason = REFUSED[name]
    assert _refusal(KEYS, make())[:2] == (code, reason)


def test_each_kind_of_key_verifies_its_own_tokens() -> None:
    for key in (ES, ED, HS):
        assert verify(KEYS, mint(key, room="r", player="p", now=NOW), now=NOW).player == "p"


def test_a_set_of_one_key_takes_tokens_without_a_kid() -> None:
    one = parse_key_set(json.dumps({"keys": [ED_PUBLIC]}), "test")
    kidless = SigningKey("EdDSA", ED.material, None)
    assert verify(one, mint(kidless, room="r", player="p", now=NOW), now=NOW).room == "r"


def test_an_unknown_kid_is_named_and_a_strange_one_is_not_shown() -> None:
    tok = mint(SigningKey("HS256", SECRET, "2025-old"), room="r", player="p", now=NOW)
    assert "'2025-old'" in _refusal(KEYS, tok)[2]
    odd = _jws({"alg": "HS256", "kid": "<script>" * 20}, CLAIMS)
    message = _refusal(KEYS, odd)[2]
    assert "script" not in message and "not shown" in message


def test_the_old_format_is_refused_naming_the_change() -> None:
    make, _, _ = REFUSED["old format"]
    message = _refusal(KEYS, make())[2]
    assert "JWT" in message and "Upgrading" in message


@pytest.mark.parametrize(
    ("room", "player"), [("r", "a b"), ("r", "p" * 65), ("lob by", "p"), ("r", "é")]
)
def test_a_room_or_player_that_is_not_a_wire_id_is_refused(room: str, player: str) -> None:
    """The player id goes out as is in welcome, presence and pose: one another client's
    decoder refuses would break that client, so such a token never admits anyone."""
    with pytest.raises(ValueError, match="not an id"):
        mint(SECRET, room=room, player=player, now=NOW)
    token = _jws({"alg": "HS256"}, {**CLAIMS, "room": room, "player": player})
    with pytest.raises(UnauthenticatedError, match="not an id"):
        verify(SECRET, token, now=NOW)


def test_expired_and_not_yet_valid() -> None:
    token = _token(ttl_s=10)
    with pytest.raises(TokenExpiredError, match="expired"):
        verify(SECRET, token, now=NOW + 10)
    verify(SECRET, token, now=NOW + 12, leeway_s=5)  # within leeway
    with pytest.raises(TokenExpiredError, match="not valid yet"):
        verify(SECRET, token, now=NOW - 60)
    verify(SECRET, token, now=NOW - 4, leeway_s=5)  # issued "in the future", within leeway


def test_replay_guard_refuses_ended_tokens_until_they_expire() -> None:
    guard = ReplayGuard(capacity=10)
    c = verify(SECRET, _token(ttl_s=100), now=NOW)
    guard.check(c, NOW)
    guard.end(c, NOW)
    with pytest.raises(UnauthenticatedError, match="already used") as info:
        guard.check(c, NOW + 50)
    assert info.value.reason == "replayed"
    guard.check(c, NOW + 100)  # expired: verify refuses it anyway; the guard forgets it
    assert len(guard) == 0


def test_replay_guard_holds_a_burned_token_through_the_verify_leeway() -> None:
    # verify() accepts a token until exp + leeway: the guard must refuse it as long.
    guard = ReplayGuard(capacity=10, leeway_s=5.0)
    token = _token(ttl_s=100, jti="burned")
    c = verify(SECRET, token, now=NOW)
    guard.end(c, NOW)
    late = NOW + 103  # past exp, within the leeway: verify still accepts the token
    assert verify(SECRET, token, now=late, leeway_s=5.0).jti == "burned"
    with pytest.raises(UnauthenticatedError, match="already used"):
        guard.check(c, late)
    guard.check(c, NOW + 105)  # past the leeway: verify refuses it anyway
    assert len(guard) == 0
    # A session ending inside the leeway still burns its token.
    c2 = verify(SECRET, _token(ttl_s=100, jti="late"), now=NOW + 102, leeway_s=5.0)
    guard.end(c2, NOW + 102)
    with pytest.raises(UnauthenticatedError):
        guard.check(c2, NOW + 104)


def test_replay_guard_is_bounded_and_forgets_the_soonest_expiring() -> None:
    guard = ReplayGuard(capacity=3)
    claims = [
        Claims("r", f"p{i}", "player", int(NOW), int(NOW) + 100 + i, f"j{i}") for i in range(5)
    ]
    for c in claims:
        guard.end(c, NOW)
    assert len(guard) == 3
    guard.check(claims[0], NOW)  # evicted
    with pytest.raises(UnauthenticatedError):
        guard.check(claims[4], NOW)
