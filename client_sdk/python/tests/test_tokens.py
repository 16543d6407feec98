"""Minted tokens are byte-for-byte the server's format."""

from __future__ import annotations

import base64
import json

import pytest

from posecast_client.tokens import mint_token

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
