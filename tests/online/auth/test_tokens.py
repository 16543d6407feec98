"""Join tokens (posecast.online.auth.tokens): mint, verify, forgery, expiry and replay."""

from __future__ import annotations

import base64
import json

import pytest

from posecast.errors import TokenExpiredError, UnauthenticatedError
from posecast.online.auth.tokens import Claims, ReplayGuard, mint, verify

SECRET = b"k" * 32
NOW = 1_700_000_000.0


def _token(**kw: object) -> str:
    args: dict[str, object] = {"room": "lobby", "player": "p1", "role": "player", "now": NOW}
    args.update(kw)
    return mint(SECRET, **args)  # type: ignore[arg-type]


def test_mint_then_verify_round_trips_every_claim() -> None:
    c = verify(SECRET, _token(ttl_s=60, jti="abc"), now=NOW + 1)
    assert (c.room, c.player, c.role, c.jti) == ("lobby", "p1", "player", "abc")
    assert (c.iat, c.exp) == (int(NOW), int(NOW) + 60)


def test_tokens_are_compact_urlsafe_and_unique() -> None:
    a, b = _token(), _token()
    assert a != b  # a fresh jti each time
    assert a.count(".") == 1 and "=" not in a and "+" not in a and "/" not in a


def test_backend_token_lists_rooms() -> None:
    c = verify(SECRET, _token(role="backend", rooms=("a", "b")), now=NOW)
    assert c.rooms == ("a", "b")
    assert c.allows_room("lobby") and c.allows_room("b") and not c.allows_room("c")


def test_only_backends_may_list_rooms() -> None:
    with pytest.raises(ValueError, match="backend"):
        _token(role="player", rooms=("a",))


@pytest.mark.parametrize(
    "tamper",
    [
        lambda t: t[:-2] + ("AA" if not t.endswith("AA") else "BB"),  # MAC changed
        lambda t: _reclaim(t, player="admin"),  # claims changed, MAC kept
        lambda t: t.replace(".", ""),  # no separator
        lambda t: t + ".x",  # three parts
        lambda t: "!!!." + t.split(".")[1],  # not base64
        lambda t: "",
    ],
)
def test_forged_or_malformed_tokens_are_unauthenticated(tamper) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(UnauthenticatedError):
        verify(SECRET, tamper(_token()), now=NOW)


def test_another_secret_does_not_verify() -> None:
    with pytest.raises(UnauthenticatedError):
        verify(b"x" * 32, _token(), now=NOW)


def test_signed_but_bad_claims_are_unauthenticated() -> None:
    payload = base64.urlsafe_b64encode(b'{"v":1,"room":"r"}').rstrip(b"=").decode()
    import hashlib
    import hmac

    mac = hmac.new(SECRET, payload.encode(), hashlib.sha256).digest()
    token = payload + "." + base64.urlsafe_b64encode(mac).rstrip(b"=").decode()
    with pytest.raises(UnauthenticatedError, match="player"):
        verify(SECRET, token, now=NOW)


@pytest.mark.parametrize(
    ("room", "player"), [("r", "a b"), ("r", "p" * 65), ("lob by", "p"), ("r", "é")]
)
def test_a_room_or_player_that_is_not_a_wire_id_is_refused(room: str, player: str) -> None:
    """The player id goes out as is in welcome, presence and pose: one another client's
    decoder refuses would break that client, so such a token never admits anyone."""
    import hashlib
    import hmac

    with pytest.raises(ValueError, match="not an id"):
        mint(SECRET, room=room, player=player, now=NOW)
    claims = {"v": 1, "room": room, "player": player, "role": "player", "jti": "j",
              "iat": int(NOW), "exp": int(NOW) + 60}  # fmt: skip
    payload = base64.urlsafe_b64encode(json.dumps(claims).encode()).rstrip(b"=").decode()
    mac = hmac.new(SECRET, payload.encode(), hashlib.sha256).digest()
    token = payload + "." + base64.urlsafe_b64encode(mac).rstrip(b"=").decode()
    with pytest.raises(UnauthenticatedError, match="not an id"):
        verify(SECRET, token, now=NOW)


def test_expired_and_not_yet_valid() -> None:
    token = _token(ttl_s=10)
    with pytest.raises(TokenExpiredError, match="expired"):
        verify(SECRET, token, now=NOW + 10)
    verify(SECRET, token, now=NOW + 12, leeway_s=5)  # within leeway
    with pytest.raises(TokenExpiredError, match="not valid yet"):
        verify(SECRET, token, now=NOW - 60)


def test_replay_guard_refuses_ended_tokens_until_they_expire() -> None:
    guard = ReplayGuard(capacity=10)
    c = verify(SECRET, _token(ttl_s=100), now=NOW)
    guard.check(c, NOW)
    guard.end(c, NOW)
    with pytest.raises(UnauthenticatedError, match="already used"):
        guard.check(c, NOW + 50)
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


def _reclaim(token: str, **changes: str) -> str:
    payload, mac = token.split(".")
    claims = json.loads(base64.urlsafe_b64decode(payload + "=" * (-len(payload) % 4)))
    claims.update(changes)
    raw = json.dumps(claims, separators=(",", ":")).encode()
    return base64.urlsafe_b64encode(raw).rstrip(b"=").decode() + "." + mac
