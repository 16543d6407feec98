"""Minted tokens are JWTs the server verifies: HS256 with a secret, ES256 and EdDSA
with a private key (the server holding the public one), each with its kid."""

from __future__ import annotations

import base64
import json

import pytest

from posecast_client.tokens import MIN_SECRET_CHARS, mint_token

SECRET = "dev-secret-0123456789-abcdefghijk"
# Minted by server/posecast/online/auth/tokens.py with the same arguments.
GOLDEN_PLAYER = (
    "eyJhbGciOiJIUzI1NiIsInR5cCI6IkpXVCJ9.eyJyb29tIjoibG9iYnkiLCJwbGF5ZXIiOiJhZGEiLCJyb2xlIjoicGxh"
    "eWVyIiwiaWF0IjoxNzAwMDAwMDAwLCJleHAiOjE3MDAwMDA2MDAsImp0aSI6ImotMSJ9."
    "TyecKK-bRxsHDcw7o2ZWdiGswDDliclFuP6O43sBC7I"
)


def _part(token: str, i: int) -> dict[str, object]:
    part = token.split(".")[i]
    return json.loads(base64.urlsafe_b64decode(part + "=" * (-len(part) % 4)))  # type: ignore[no-any-return]


def test_golden_token() -> None:
    player = mint_token(SECRET, room="lobby", player="ada", ttl_s=600, now=1700000000.5, jti="j-1")
    assert player == GOLDEN_PLAYER
    assert _part(player, 0) == {"alg": "HS256", "typ": "JWT"}
    assert _part(player, 1) == {"room": "lobby", "player": "ada", "role": "player",
                                "iat": 1700000000, "exp": 1700000600, "jti": "j-1"}  # fmt: skip


def test_the_server_verifies_minted_tokens() -> None:
    tokens = pytest.importorskip("posecast.online.auth.tokens")
    tok = mint_token(SECRET, room="r", player="p", role="spectator", now=1000.0)
    claims = tokens.verify(SECRET.encode(), tok, now=1001.0)
    assert (claims.room, claims.player, claims.role, claims.exp) == ("r", "p", "spectator", 4600)


@pytest.mark.parametrize("alg", ["ES256", "EdDSA", "HS256"])
def test_a_key_pair_mints_what_a_server_with_the_public_key_verifies(alg: str) -> None:
    keys = pytest.importorskip("posecast.online.auth.keys")
    tokens = pytest.importorskip("posecast.online.auth.tokens")
    private, public = keys.generate(alg, "k-" + alg)
    other, _ = keys.generate(alg, "k-other")
    key_set = keys.parse_key_set(json.dumps({"keys": [public, _]}), "test")
    tok = mint_token(private, room="r", player="p", role="backend", rooms=("b",), now=1000.0)
    assert _part(tok, 0)["kid"] == "k-" + alg and _part(tok, 0)["alg"] == alg
    assert tokens.verify(key_set, tok, now=1001.0).rooms == ("b",)
    assert mint_token(private, room="r", player="p", alg=alg, kid="k-" + alg)
    with pytest.raises(ValueError, match="does not fit"):
        mint_token(private, room="r", player="p", alg="HS256" if alg != "HS256" else "ES256")
    if alg != "HS256":
        with pytest.raises(ValueError, match="public key"):
            mint_token(public, room="r", player="p")
    forged = mint_token(other, room="r", player="p", now=1000.0, kid="k-" + alg)
    with pytest.raises(tokens.UnauthenticatedError, match="signature"):
        tokens.verify(key_set, forged, now=1001.0)


@pytest.mark.parametrize(
    "kw",
    [
        {"key": ""},
        {"key": "dev"},
        {"key": "s" * 31},
        {"key": b"s" * 31},
        {"key": {"kty": "RSA", "n": "AQAB", "e": "AQAB"}},  # no kind posecast verifies
        {"key": b"\xff" * 32},  # not UTF-8: no server's secret
        {"role": "admin"},
        {"rooms": ("x",)},
        {"ttl_s": 0},
        {"ttl_s": 8 * 86400},
        {"player": "a b"},
        {"player": "p" * 65},
        {"room": "lob by"},
        {"room": ""},
        {"role": "backend", "rooms": ("ok", "not ok")},
    ],
)
def test_bad_requests_are_refused(kw: dict[str, object]) -> None:
    args: dict[str, object] = {"key": SECRET, "room": "r", "player": "p", **kw}
    with pytest.raises(ValueError):
        mint_token(**args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("secret", "chars"),
    [
        ("dev", 3),
        ("s" * 31, 31),
        ("é" * 16, 16),
        ("é" * 16 + "s" * 15, 31),
        (b"s" * 31, 31),
        (("é" * 16).encode(), 16),
    ],
)
def test_a_secret_no_server_takes_is_refused(secret: str | bytes, chars: int) -> None:
    """Characters count as the server counts them (32 bytes of UTF-8 can be 16 characters):
    a token minted with a shorter secret fails at join time, far from the mistake."""
    want = f"the secret has {chars} characters; a server takes none under {MIN_SECRET_CHARS}"
    with pytest.raises(ValueError, match=want):
        mint_token(secret, room="r", player="p")


@pytest.mark.parametrize("secret", ["s" * 32, "é" * 32, "é" * 16 + "s" * 16, ("é" * 32).encode()])
def test_a_secret_the_server_takes_mints(secret: str | bytes) -> None:
    tok = mint_token(secret, room="r", player="p", now=1000.0)
    config = pytest.importorskip("posecast.online.config")
    text = secret if isinstance(secret, str) else secret.decode()
    config.ServerConfig(token_secret=text)  # the server starts with it
    tokens = pytest.importorskip("posecast.online.auth.tokens")
    assert tokens.verify(text.encode(), tok, now=1001.0).player == "p"


def test_the_server_refuses_what_mint_token_refuses() -> None:
    config = pytest.importorskip("posecast.online.config")
    assert config.MIN_SECRET_CHARS == MIN_SECRET_CHARS
    for text in ("s" * 31, "é" * 31):
        with pytest.raises(config.ConfigError):
            config.ServerConfig(token_secret=text)
