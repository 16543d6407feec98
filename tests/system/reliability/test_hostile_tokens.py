"""Token attacks against a running room: forged, tampered, signed with the wrong key
or algorithm (``none``, HS256 keyed with a public key), an unknown ``kid``, a missing
claim, the pre-JWT format, expired, not yet valid, for another room, replayed after
``bye``, and a spectator sending frames.

The server holds a key set of three kinds (its HS256 secret, an ES256 and an EdDSA
public key); tokens signed with each private key join. Every refusal is counted in
``/metrics`` under its code and under its reason (``posecast_token_refusals_total``).

Each refused ``hello`` gets exactly one message, its ``error`` (fatal, close 1008 with
the code as reason): no ``welcome``, no presence, no pose of the room. The spectator
is refused every frame (FORBIDDEN, not fatal) and its frames never become a pose.
Meanwhile the healthy players of the :class:`Arena` keep their pose rate.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import time
from collections.abc import Iterator

import pytest
from websockets.exceptions import ConnectionClosed

from posecast.online.auth.keys import SigningKey, generate
from posecast.online.auth.tokens import mint
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import Bye, Error, Hello, Message, Welcome
from tests.online.conftest import SECRET, make_cfg, token, walk_frame
from tests.system.reliability.arena import (
    Arena,
    assert_rates_kept,
    delta,
    errors_by_code,
    scrape,
    token_refusals,
)
from tests.system.reliability.flooder import as_attacker
from tests.system.reliability.hostile_helpers import Attacker

pytestmark = pytest.mark.timeout(120)


ES_PRIVATE, ES_PUBLIC = generate("ES256", "es-1")
ED_PRIVATE, ED_PUBLIC = generate("EdDSA", "ed-1")
ES, ED = SigningKey.from_jwk(ES_PRIVATE), SigningKey.from_jwk(ED_PRIVATE)
KEYS = json.dumps({"keys": [ES_PUBLIC, ED_PUBLIC]})


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    with Arena(make_cfg(lookahead=1, token_leeway_s=1.0, token_keys=KEYS)) as a:
        yield a


def _b64(raw: bytes) -> str:
    return base64.urlsafe_b64encode(raw).rstrip(b"=").decode()


def _hs256(header: dict[str, object], claims: dict[str, object], key: bytes) -> str:
    """A compact JWS signed HMAC-SHA256 with ``key``, whatever ``header`` says."""
    first = _b64(json.dumps(header).encode()) + "." + _b64(json.dumps(claims).encode())
    return first + "." + _b64(hmac.new(key, first.encode(), hashlib.sha256).digest())


def _public_pem() -> bytes:
    """The ES256 key's public half as PEM: public knowledge, and what an algorithm
    confusion attack keys HS256 with."""
    from cryptography.hazmat.primitives import serialization

    return ES.material.public_key().public_bytes(  # type: ignore[no-any-return]
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )


def _everything_after_hello(port: int, tok: str, room: str = "r1") -> list[Message]:
    """Send ``hello`` and read every message until the server closes (or 3 s)."""
    att = Attacker(port)
    att.ws.send(encode(Hello(1, tok, room, "Mallory")))
    got: list[Message] = []
    deadline = time.monotonic() + 3.0
    try:
        while time.monotonic() < deadline:
            raw = att.ws.recv(timeout=deadline - time.monotonic())
            assert isinstance(raw, bytes)
            got.append(decode(raw))
    except ConnectionClosed:
        assert (att.ws.close_code, att.ws.close_reason) == (1008, getattr(got[-1], "code", ""))
    except TimeoutError:
        pass
    att.close()
    return got


def _tamper(tok: str, **claims: object) -> str:
    """The token with its claims edited and the original header and signature kept."""
    header, payload, sig = tok.split(".")
    c = json.loads(base64.urlsafe_b64decode(payload + "=" * (-len(payload) % 4)))
    c.update(claims)
    return header + "." + _b64(json.dumps(c, separators=(",", ":")).encode()) + "." + sig


def test_token_attacks_get_their_codes_and_no_room_data(arena: Arena) -> None:
    port, now = arena.port, time.time()
    used = token("r1", "leaver")
    leaver = Attacker(port)
    assert isinstance(leaver.hello(used), Welcome)
    leaver.ws.send(encode(Bye("done")))
    leaver.next(lambda m: isinstance(m, Bye))
    leaver.close()

    # Every kind of key in the set admits its tokens (one each, then gone).
    for key, who in ((ES, "es-player"), (ED, "ed-player"), (SigningKey.from_secret(SECRET), "hs")):
        joiner = Attacker(port)
        assert isinstance(joiner.hello(mint(key, room="r1", player=who, now=now)), Welcome), who
        joiner.close()

    good = token("r1", "mallory")
    claims = {"room": "r1", "player": "mallory", "role": "player", "iat": int(now),
              "exp": int(now) + 60, "jti": "j-mallory"}  # fmt: skip
    no_jti = {k: v for k, v in claims.items() if k != "jti"}
    wrong_es = SigningKey.from_jwk(generate("ES256", "es-1")[0])  # a kid the server knows
    old_format = _b64(json.dumps({"v": 1, **claims}).encode()) + "." + _b64(b"m" * 32)
    attacks = {  # name: (token, room, expected code, reason)
        "forged signature": (good[:-6] + ("AAAAAA" if good[-6:] != "AAAAAA" else "BBBBBB"),
                             "r1", "UNAUTHENTICATED", "bad_signature"),
        "other secret": (mint(SigningKey.from_secret(b"not-the-server-secret-at-all-32b!"),
                              room="r1", player="mallory", now=now),
                         "r1", "UNAUTHENTICATED", "bad_signature"),
        "wrong ES256 key": (mint(wrong_es, room="r1", player="mallory", now=now),
                            "r1", "UNAUTHENTICATED", "bad_signature"),
        "claims edited, signature kept": (_tamper(good, room="r2"), "r2", "UNAUTHENTICATED",
                                          "bad_signature"),
        "spectator made player": (_tamper(mint(ED, room="r1", player="m2", role="spectator",
                                               now=now), role="player"),
                                  "r1", "UNAUTHENTICATED", "bad_signature"),
        "alg none": (_b64(b'{"alg":"none","kid":"es-1"}') + "." + _b64(json.dumps(claims).encode())
                     + ".", "r1", "UNAUTHENTICATED", "alg_refused"),
        "HS256 keyed with the public key": (_hs256({"alg": "HS256", "kid": "es-1"}, claims,
                                                   _public_pem()),
                                            "r1", "UNAUTHENTICATED", "alg_mismatch"),
        "EdDSA naming the ES256 key": (mint(SigningKey("EdDSA", ED.material, "es-1"), room="r1",
                                            player="mallory", now=now),
                                       "r1", "UNAUTHENTICATED", "alg_mismatch"),
        "unknown kid": (mint(SigningKey("EdDSA", ED.material, "retired-2025"), room="r1",
                             player="mallory", now=now), "r1", "UNAUTHENTICATED", "unknown_kid"),
        "missing claim": (_hs256({"alg": "HS256", "kid": "secret"}, no_jti, SECRET.encode()),
                          "r1", "UNAUTHENTICATED", "bad_claims"),
        "old format": (old_format, "r1", "UNAUTHENTICATED", "old_format"),
        "no token": ("", "r1", "UNAUTHENTICATED", "missing"),
        "garbage": ("x" * 4000, "r1", "UNAUTHENTICATED", "malformed"),
        "expired": (mint(ES, room="r1", player="mallory", ttl_s=60, now=now - 120),
                    "r1", "TOKEN_EXPIRED", "expired"),
        "not yet valid": (mint(ED, room="r1", player="mallory", ttl_s=60, now=now + 60),
                          "r1", "TOKEN_EXPIRED", "not_yet_valid"),
        "room claim mismatch": (token("r2", "mallory"), "r1", "FORBIDDEN", None),
        "replay after bye": (used, "r1", "UNAUTHENTICATED", "replayed"),
    }  # fmt: skip
    refusals_before = token_refusals(scrape(port))
    baseline = arena.baseline()
    before = errors_by_code(scrape(port))

    def attack() -> int:
        rounds, t0 = 0, time.monotonic()
        while rounds == 0 or time.monotonic() - t0 < 2.0:  # a window long enough to measure
            for name, (tok, room, code, _) in attacks.items():
                got = _everything_after_hello(port, tok, room)
                summary = [(type(m), getattr(m, "code", None), getattr(m, "fatal", None))
                           for m in got]  # fmt: skip
                assert summary == [(Error, code, True)], name
            rounds += 1
        return rounds

    with arena.window() as during:
        rounds = as_attacker(attack)
    print(f"token attacks: {rounds} rounds of {len(attacks)} attacks")
    want = {
        code: rounds * sum(c == code for _, _, c, _ in attacks.values())
        for _, _, code, _ in attacks.values()
    }
    after = scrape(port)
    assert delta(errors_by_code(after), before) == want
    by_reason = {
        reason: rounds * sum(r == reason for *_, r in attacks.values())
        for *_, reason in attacks.values()
        if reason is not None
    }
    assert delta(token_refusals(after), refusals_before) == by_reason
    assert token_refusals(after).keys() >= set(by_reason)  # each one counted under its name
    for player in arena.clients:
        assert arena.errors_of(player) == []
    assert_rates_kept(during[0], baseline, "token attacks")


def test_a_spectator_sending_frames_is_refused_and_makes_no_pose(arena: Arena) -> None:
    port = arena.port
    before = errors_by_code(scrape(port))
    spy = Attacker(port)
    assert isinstance(spy.hello(token("r1", "spy", role="spectator")), Welcome)
    refused = []
    for seq in range(15):  # within the control and error budgets (20 each)
        ans = spy.probe(encode(walk_frame(seq, seed=3)))
        refused += [(e.code, e.fatal, e.field) for e in ans.errors]
        assert ans.pong, "the spectator was cut off"
    assert refused == [("FORBIDDEN", False, "type")] * 15
    time.sleep(0.3)  # a pose would be out within a tick or two
    senders = arena.report()["senders"]
    assert all("spy" not in got for got in senders.values()), senders
    assert arena.server is not None
    assert arena.server.metric("posecast_players") == len(arena.clients)  # spy never played
    assert delta(errors_by_code(scrape(port)), before) == {"FORBIDDEN": 15}
    spy.close()
