"""Token attacks against a running room: forged, tampered, expired, not yet valid,
for another room, replayed after ``bye``, and a spectator sending frames.

Each refused ``hello`` gets exactly one message, its ``error`` (fatal, close 1008 with
the code as reason): no ``welcome``, no presence, no pose of the room. The spectator
is refused every frame (FORBIDDEN, not fatal) and its frames never become a pose.
Meanwhile the healthy players of the :class:`Arena` keep their pose rate.
"""

from __future__ import annotations

import base64
import json
import time
from collections.abc import Iterator

import pytest
from websockets.exceptions import ConnectionClosed

from posecast.online.auth.tokens import mint
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import Bye, Error, Hello, Message, Welcome
from tests.online.conftest import SECRET, make_cfg, token, walk_frame
from tests.system.reliability.hostile_helpers import (
    Arena,
    Attacker,
    as_attacker,
    assert_rates_kept,
    delta,
    errors_by_code,
    scrape,
)

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    with Arena(make_cfg(lookahead=1, token_leeway_s=1.0)) as a:
        yield a


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
    """The token with its claims edited and the original MAC kept."""
    payload, mac = tok.split(".")
    c = json.loads(base64.urlsafe_b64decode(payload + "=" * (-len(payload) % 4)))
    c.update(claims)
    raw = json.dumps(c, separators=(",", ":"), sort_keys=True).encode()
    return base64.urlsafe_b64encode(raw).rstrip(b"=").decode() + "." + mac


def test_token_attacks_get_their_codes_and_no_room_data(arena: Arena) -> None:
    port, now = arena.port, time.time()
    used = token("r1", "leaver")
    leaver = Attacker(port)
    assert isinstance(leaver.hello(used), Welcome)
    leaver.ws.send(encode(Bye("done")))
    leaver.next(lambda m: isinstance(m, Bye))
    leaver.close()

    good = token("r1", "mallory")
    attacks = {  # name: (token, room, expected code)
        "forged signature": (good[:-6] + ("AAAAAA" if good[-6:] != "AAAAAA" else "BBBBBB"),
                             "r1", "UNAUTHENTICATED"),
        "other secret": (mint(b"not-the-server-secret-at-all", room="r1", player="mallory",
                              now=now), "r1", "UNAUTHENTICATED"),
        "claims edited, MAC kept": (_tamper(good, room="r2"), "r2", "UNAUTHENTICATED"),
        "spectator made player": (_tamper(token("r1", "m2", role="spectator"), role="player"),
                                  "r1", "UNAUTHENTICATED"),
        "no token": ("", "r1", "UNAUTHENTICATED"),
        "garbage": ("x" * 4000, "r1", "UNAUTHENTICATED"),
        "expired": (mint(SECRET.encode(), room="r1", player="mallory", ttl_s=60,
                         now=now - 120), "r1", "TOKEN_EXPIRED"),
        "not yet valid": (mint(SECRET.encode(), room="r1", player="mallory", ttl_s=60,
                               now=now + 60), "r1", "TOKEN_EXPIRED"),
        "room claim mismatch": (token("r2", "mallory"), "r1", "FORBIDDEN"),
        "replay after bye": (used, "r1", "UNAUTHENTICATED"),
    }  # fmt: skip
    baseline = arena.baseline()
    before = errors_by_code(scrape(port))

    def attack() -> int:
        rounds, t0 = 0, time.monotonic()
        while rounds == 0 or time.monotonic() - t0 < 2.0:  # a window long enough to measure
            for name, (tok, room, code) in attacks.items():
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
        code: rounds * sum(c == code for _, _, c in attacks.values())
        for _, _, code in attacks.values()
    }
    assert delta(errors_by_code(scrape(port)), before) == want
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
