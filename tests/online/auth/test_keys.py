"""Token key sets (posecast.online.auth.keys) and how the config builds and reloads one."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from posecast.errors import ConfigError
from posecast.online.auth.keys import (
    SECRET_KID,
    SigningKey,
    generate,
    parse_key_set,
)
from posecast.online.auth.tokens import mint, verify
from posecast.online.config import ServerConfig

NOW = 1_700_000_000.0
SECRET = "s" * 32


def _set(*jwks: object) -> str:
    return json.dumps({"keys": list(jwks)})


@pytest.mark.parametrize("alg", ["ES256", "EdDSA", "HS256"])
def test_generated_pairs_round_trip(alg: str) -> None:
    private, public = generate(alg, "k1")
    assert private["kid"] == public["kid"] == "k1" and public["alg"] == alg
    if alg != "HS256":
        assert "d" in private and "d" not in public
    keys = parse_key_set(_set(public), "test")
    tok = mint(SigningKey.from_jwk(private), room="r", player="p", now=NOW)
    assert verify(keys, tok, now=NOW).player == "p"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("not json", "not JSON"),
        ('{"keys": []}', "at least one key"),
        ("[1]", "not a key set"),
        (_set({"kty": "oct", "k": "a" * 43}), "needs a kid"),
        (_set({"kty": "oct", "k": "a" * 43, "kid": "bad kid"}), "needs a kid"),
        (_set({"kty": "oct", "k": "YWJj", "kid": "k"}), "at least 32"),
        (_set({"kty": "RSA", "n": "x", "e": "AQAB", "kid": "k"}), "not a key kind"),
        (_set({"kty": "EC", "crv": "P-384", "x": "a", "y": "b", "kid": "k"}), "not a key kind"),
        (_set({**generate("ES256", "k")[1], "alg": "HS256"}), "verifies ES256"),
        (_set(generate("ES256", "k")[0]), "private key"),
        (_set(generate("EdDSA", "k")[0]), "private key"),
        (_set({"kty": "EC", "crv": "P-256", "x": "AAAA", "y": "AAAA", "kid": "k"}), "not a valid"),
        (_set(generate("EdDSA", "k")[1], generate("ES256", "k")[1]), "two keys with kid 'k'"),
    ],
)
def test_bad_key_sets_are_refused_by_name_without_their_material(text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        parse_key_set(text, "POSECAST_TOKEN_KEYS")
    assert "POSECAST_TOKEN_KEYS" in info.value.message
    for jwk in json.loads(text).get("keys", []) if text.startswith("{") else []:
        for part in ("k", "d", "x"):
            if isinstance(jwk, dict) and len(str(jwk.get(part, ""))) > 8:
                assert str(jwk[part]) not in info.value.message


def test_the_config_joins_secret_keys_and_file(tmp_path: Path) -> None:
    es_private, es_public = generate("ES256", "es")
    ed_private, ed_public = generate("EdDSA", "ed")
    path = tmp_path / "keys.json"
    path.write_text(_set(ed_public))
    cfg = ServerConfig(token_secret=SECRET, token_keys=_set(es_public), token_keys_file=str(path))
    keys = cfg.key_set()
    assert sorted(keys.keys) == ["ed", "es", SECRET_KID]
    for key in (SigningKey.from_jwk(es_private), SigningKey.from_jwk(ed_private),
                SigningKey.from_secret(SECRET)):  # fmt: skip
        assert verify(keys, mint(key, room="r", player="p", now=NOW), now=NOW).room == "r"
    assert SECRET not in repr(cfg) and es_public["x"] not in repr(cfg)


def test_a_config_with_no_key_or_a_bad_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no token secret or key set"):
        ServerConfig()
    with pytest.raises(ConfigError, match=r"token key file .*missing\.json"):
        ServerConfig(token_keys_file=str(tmp_path / "missing.json"))
    ServerConfig(token_keys=_set(generate("EdDSA", "ed")[1]))  # a key set alone will do
    dev = ServerConfig.from_sources({"POSECAST_TOKEN_KEYS": _set(generate("EdDSA", "e")[1])},
                                    {"dev": True})  # fmt: skip
    assert dev.token_secret == ""  # --dev invents a secret only where no key is set


def test_the_file_is_read_again_on_each_key_set(tmp_path: Path) -> None:
    """What the shell's reload (SIGHUP, interval) calls: a rotation is an edit of the file."""
    old_private, old_public = generate("EdDSA", "2026-11")
    new_private, new_public = generate("EdDSA", "2026-12")
    path = tmp_path / "keys.json"
    path.write_text(_set(old_public))
    cfg = ServerConfig(token_keys_file=str(path))
    old_tok = mint(SigningKey.from_jwk(old_private), room="r", player="p", now=NOW)
    new_tok = mint(SigningKey.from_jwk(new_private), room="r", player="p", now=NOW)
    assert verify(cfg.key_set(), old_tok, now=NOW)
    path.write_text(_set(old_public, new_public))  # 1. add the new key
    both = cfg.key_set()
    assert verify(both, old_tok, now=NOW) and verify(both, new_tok, now=NOW)
    path.write_text(_set(new_public))  # 2. after the longest token lifetime: drop the old
    with pytest.raises(Exception, match="kid '2026-11' is unknown"):
        verify(cfg.key_set(), old_tok, now=NOW)
    path.write_text("{half written")
    with pytest.raises(ConfigError, match="not JSON"):
        cfg.key_set()
