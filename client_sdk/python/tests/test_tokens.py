"""Minted tokens are byte-for-byte the server's format."""

from __future__ import annotations

import base64
import json

import pytest

from posecast_client.tokens import MIN_SECRET_CHARS, mint_token

SECRET = "dev-secret-0123456789"
# Minted by server/posecast/online/auth/tokens.py with the same arguments.
GOLDEN_PLAYER = (
    "eyJleHAiOjE3MDAwMDA2MDAsImlhdCI6MTcwMDAwMDAwMCwianRpIjoiai0xIiwicGxheWVyIjoiYWRhIiwicm9sZSI6"
    "InBsYXllciIsInJvb20iOiJsb2JieSIsInYiOjF9.25UbpyGLcJ3Gx9fQuf04BaNpBL51CSum7sQn_ctNe2c"
)
GOLDEN_BACKEND = (
    "eyJleHAiOjE3MDAwMDA2MDAsImlhdCI6MTcwMDAwMDAwMCwianRpIjoiai0yIiwicGxheWVyIjoib3BzIiwicm9sZSI6"
    "ImJhY2tlbmQiLCJyb29tIjoibG9iYnkiLCJyb29tcyI6WyJhIiwiYiJdLCJ2IjoxfQ."
    "GZ4Law7x8KU2cVEaSElKngM_E_qVE6kKLrS9vukKupc"
)


def test_golden_tokens() -> None:
    player = mint_token(SECRET, room="lobby", player="ada", ttl_s=600, now=1700000000.5, jti="j-1")
    assert player == GOLDEN_PLAYER
    backend = mint_token(SECRET.encode(), room="lobby", player="ops", role="backend", ttl_s=600,
                         now=1700000000, rooms=("a", "b"), jti="j-2")  # fmt: skip
    assert backend == GOLDEN_BACKEND
    claims = json.loads(base64.urlsafe_b64decode(player.split(".")[0] + "=="))
    assert claims == {"v": 1, "room": "lobby", "player": "ada", "role": "player",
                      "iat": 1700000000, "exp": 1700000600, "jti": "j-1"}  # fmt: skip


def test_the_server_verifies_minted_tokens() -> None:
    tokens = pytest.importorskip("posecast.online.auth.tokens")
    tok = mint_token(SECRET, room="r", player="p", role="spectator", now=1000.0)
    claims = tokens.verify(SECRET.encode(), tok, now=1001.0)
    assert (claims.room, claims.player, claims.role, claims.exp) == ("r", "p", "spectator", 4600)


@pytest.mark.parametrize(
    "kw",
    [
        {"secret": ""},
        {"secret": "dev"},
        {"secret": "s" * 15},
        {"secret": b"s" * 15},
        {"secret": b"\xff" * 32},  # not UTF-8: no server's secret
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
    args: dict[str, object] = {"secret": SECRET, "room": "r", "player": "p", **kw}
    with pytest.raises(ValueError):
        mint_token(**args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("secret", "chars"),
    [
        ("dev", 3),
        ("s" * 15, 15),
        ("é" * 8, 8),
        ("é" * 8 + "s" * 7, 15),
        (b"s" * 15, 15),
        (("é" * 8).encode(), 8),
    ],
)
def test_a_secret_no_server_takes_is_refused(secret: str | bytes, chars: int) -> None:
    """Characters count as the server counts them (16 bytes of UTF-8 can be 8 characters):
    a token minted with a shorter secret fails at join time, far from the mistake."""
    want = f"the secret has {chars} characters; a server takes none under {MIN_SECRET_CHARS}"
    with pytest.raises(ValueError, match=want):
        mint_token(secret, room="r", player="p")


@pytest.mark.parametrize("secret", ["s" * 16, "é" * 16, "é" * 8 + "s" * 8, ("é" * 16).encode()])
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
    for text in ("s" * 15, "é" * 15):
        with pytest.raises(config.ConfigError):
            config.ServerConfig(token_secret=text)
