"""Token keys: the key set a server verifies join tokens with, and minting keys.

A key set is JWKS-shaped (RFC 7517): ``{"keys": [JWK, ...]}``, every key with a ``kid``.
Three kinds of key, each verifying exactly one algorithm (:data:`ALGORITHMS`); the
key, never the token, decides which, so a token cannot pick how it is checked
(the "algorithm confusion" of HS256-signed tokens checked with a public key)::

    kty   crv       alg     a node holds
    oct   -         HS256   the shared secret (the backend holds the same one)
    EC    P-256     ES256   the public key only (x, y); the backend keeps d
    OKP   Ed25519   EdDSA   the public key only (x); the backend keeps d

A private key (``d``) in a server's key set is refused: a node needs only the public
half, and one that holds the private half can mint tokens when it is compromised.
HS256 secrets are at least :data:`MIN_SECRET_BYTES` bytes (RFC 7518, 3.2).

The key set comes from configuration only (``POSECAST_TOKEN_KEYS``, a file named by
``--token-keys-file``, and ``POSECAST_TOKEN_SECRET`` as one HS256 key whose ``kid`` is
:data:`SECRET_KID`); :mod:`posecast.online.config` builds it, the shell reloads the
file on SIGHUP or an interval. Parsing is pure: text in, :class:`KeySet` out.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import jwt
from jwt.algorithms import ECAlgorithm, OKPAlgorithm

from posecast.errors import ConfigError

# alg -> (kty, crv): the one kind of key that verifies it. Nothing else is accepted
# (never "none"; no RSA, no HS384/512: one algorithm per kind keeps the rule simple).
ALGORITHMS: dict[str, tuple[str, str | None]] = {
    "HS256": ("oct", None),
    "ES256": ("EC", "P-256"),
    "EdDSA": ("OKP", "Ed25519"),
}
PUBLIC_KEY_ALGORITHMS = ("ES256", "EdDSA")
MIN_SECRET_BYTES = 32  # RFC 7518 3.2: an HS256 key is at least as long as the hash
SECRET_KID = "secret"  # the kid of POSECAST_TOKEN_SECRET's key in the key set
KID_PATTERN = re.compile(r"[A-Za-z0-9_.:-]{1,64}")
MAX_KEYS = 64


@dataclass(frozen=True, slots=True)
class Key:
    """One verifying key: its ``kid``, the one ``alg`` it verifies, and the key
    material PyJWT takes (the secret's bytes, or a public key object)."""

    kid: str
    alg: str
    material: Any

    def __repr__(self) -> str:  # never the secret
        return f"Key(kid={self.kid!r}, alg={self.alg!r})"


@dataclass(frozen=True, slots=True)
class KeySet:
    """The keys a server verifies tokens with, by ``kid``. Immutable: a reload builds
    a new one and the verifier swaps it in whole."""

    keys: Mapping[str, Key]

    def __len__(self) -> int:
        return len(self.keys)

    def __repr__(self) -> str:
        return f"KeySet({', '.join(f'{k.kid}:{k.alg}' for k in self.keys.values())})"

    def describe(self) -> list[dict[str, str]]:
        """``[{"kid": ..., "alg": ...}]``: what a log may say about the set."""
        return [{"kid": k.kid, "alg": k.alg} for k in self.keys.values()]

    @classmethod
    def of(cls, keys: Iterable[Key]) -> KeySet:
        out: dict[str, Key] = {}
        for key in keys:
            if key.kid in out:
                raise ConfigError(f"the token key set has two keys with kid {key.kid!r}")
            out[key.kid] = key
        if len(out) > MAX_KEYS:
            raise ConfigError(f"the token key set has {len(out)} keys: at most {MAX_KEYS}")
        return cls(out)

    @classmethod
    def from_secret(cls, secret: str | bytes, kid: str = SECRET_KID) -> KeySet:
        """One HS256 key: the shared secret (text is keyed as UTF-8)."""
        return cls.of([secret_key(secret, kid)])


def secret_key(secret: str | bytes, kid: str = SECRET_KID, where: str = "") -> Key:
    raw = secret.encode("utf-8") if isinstance(secret, str) else secret
    if len(raw) < MIN_SECRET_BYTES:
        raise ConfigError(
            f"{where or f'HS256 key {kid!r}'} has {len(raw)} bytes: a token secret must be"
            f" at least {MIN_SECRET_BYTES} (RFC 7518 3.2)"
        )
    return Key(kid, "HS256", raw)


def parse_key_set(text: str, source: str) -> KeySet:
    """The key set in ``text`` (JWKS JSON), or :class:`ConfigError` naming ``source``
    (``POSECAST_TOKEN_KEYS``, a file name) and the key at fault by index and kid. The
    key material is never shown."""
    try:
        doc = json.loads(text)
    except ValueError:
        raise ConfigError(f'{source} is not JSON: a key set is {{"keys": [JWK, ...]}}') from None
    if not isinstance(doc, dict) or not isinstance(doc.get("keys"), list) or not doc["keys"]:
        raise ConfigError(f'{source} is not a key set: {{"keys": [JWK, ...]}}, at least one key')
    keys = [parse_jwk(jwk, f"{source} key {i}") for i, jwk in enumerate(doc["keys"])]
    try:
        return KeySet.of(keys)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc.message}") from None


def parse_jwk(jwk: object, where: str) -> Key:
    """One verifying key from a public JWK (or an ``oct`` one)."""
    if not isinstance(jwk, dict):
        raise ConfigError(f"{where} is not a JSON object (a JWK)")
    kid = jwk.get("kid")
    if not isinstance(kid, str) or not KID_PATTERN.fullmatch(kid):
        raise ConfigError(f"{where} needs a kid: 1 to 64 of A-Z a-z 0-9 _ . : -")
    where = f"{where} (kid {kid!r})"
    alg = _alg_of(jwk, where)
    if alg != "HS256" and "d" in jwk:
        raise ConfigError(
            f"{where} holds a private key (d): give servers the public key only, keep the"
            " private one with the game backend (posecast token keygen prints both)"
        )
    try:
        material = jwt.PyJWK(jwk, algorithm=alg).key
    except jwt.PyJWTError:  # its message may quote the key: not shown
        raise ConfigError(f"{where} is not a valid {alg} key") from None
    if alg == "HS256":
        return secret_key(material, kid, where)
    return Key(kid, alg, material)


def _alg_of(jwk: Mapping[str, Any], where: str) -> str:
    """The algorithm this JWK verifies, from its kty (and crv); an ``alg`` member must
    agree."""
    for alg, (kty, crv) in ALGORITHMS.items():
        if jwk.get("kty") == kty and (crv is None or jwk.get("crv") == crv):
            if jwk.get("alg", alg) != alg:
                raise ConfigError(f"{where}: a {kty} key verifies {alg}, not {jwk['alg']!r}")
            return alg
    kinds = ", ".join(f"{k}{'/' + c if c else ''} ({a})" for a, (k, c) in ALGORITHMS.items())
    raise ConfigError(f"{where} is not a key kind posecast verifies: {kinds}")


# --- minting keys (the game backend's side; posecast token, tests, benchmarks) ---------


@dataclass(frozen=True, slots=True)
class SigningKey:
    """What mints tokens: the ``alg``, the ``kid`` written in the header (``None``:
    no kid, for a server whose key set holds one key) and the secret or private key."""

    alg: str
    material: Any
    kid: str | None = None

    def __repr__(self) -> str:
        return f"SigningKey(alg={self.alg!r}, kid={self.kid!r})"

    @classmethod
    def from_secret(cls, secret: str | bytes, kid: str | None = SECRET_KID) -> SigningKey:
        """HS256 with ``secret``; by default with the ``kid`` of the server's
        ``POSECAST_TOKEN_SECRET`` key, which finds it in a set of several keys."""
        return cls("HS256", secret.encode("utf-8") if isinstance(secret, str) else secret, kid)

    @classmethod
    def from_jwk(cls, jwk: Mapping[str, Any]) -> SigningKey:
        """From a private JWK (``posecast token keygen``'s file) or an ``oct`` one."""
        where = f"key {jwk.get('kid')!r}"
        alg = _alg_of(jwk, where)
        if alg != "HS256" and "d" not in jwk:
            raise ValueError(f"{where} is a public key: minting needs the private one (d)")
        try:
            material = jwt.PyJWK(dict(jwk), algorithm=alg).key
        except jwt.PyJWTError:
            raise ValueError(f"{where} is not a valid {alg} key") from None
        kid = jwk.get("kid")
        return cls(alg, material, kid if isinstance(kid, str) else None)


def generate(alg: str, kid: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """A new key pair as ``(private JWK, public JWK)``, both with ``kid`` and ``alg``.
    For HS256 both are the same secret (32 random bytes)."""
    import base64
    import secrets

    from cryptography.hazmat.primitives.asymmetric import ec, ed25519

    if alg == "HS256":
        k = base64.urlsafe_b64encode(secrets.token_bytes(32)).rstrip(b"=").decode()
        jwk = {"kty": "oct", "k": k, "kid": kid, "alg": alg}
        return jwk, dict(jwk)
    if alg == "ES256":
        ec_key = ec.generate_private_key(ec.SECP256R1())
        private = json.loads(ECAlgorithm.to_jwk(ec_key))
        public = json.loads(ECAlgorithm.to_jwk(ec_key.public_key()))
    elif alg == "EdDSA":
        ed_key = ed25519.Ed25519PrivateKey.generate()
        private = json.loads(OKPAlgorithm.to_jwk(ed_key))
        public = json.loads(OKPAlgorithm.to_jwk(ed_key.public_key()))
    else:
        raise ValueError(f"alg must be one of {', '.join(ALGORITHMS)}, not {alg!r}")
    for jwk in (private, public):
        jwk.update(kid=kid, alg=alg, use="sig")
    return private, public
