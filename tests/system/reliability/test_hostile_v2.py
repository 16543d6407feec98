"""Hostile input over ``posecast.v2``: every v2 message and field, malformed, oversized
and out of range, against a real server with healthy players streaming.

Two joined v2 attackers (a player in the healthy players' room, a backend in a room
of its own) send every single-message vector that holds in v2 (the invalid ones and
the valid ones: a server-to-client type from a client is FORBIDDEN), then what
hypothesis builds from the v2 client messages: ``hello.pose_rate_hz`` and
``forecast_ms``, ``pose_rate``, ``forecast`` and ``resync`` with boundary, wrong-kind
and random values, truncated and oversized v2 encodings, ``poses``/``skeleton`` from
a client. Each answer is checked against the spec
(:func:`~tests.system.reliability.hostile_helpers.verdict`, v2), ``/metrics`` counted
every error by its code, nobody else heard a thing and the server answers
``/healthz``. (The healthy players' pose rate is held to its floor by
``test_hostile_fuzz``; on a saturated machine that floor fails with or without v2.)
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.system.reliability.arena import Arena, delta, errors_by_code, http_get, scrape
from tests.system.reliability.flooder import as_attacker
from tests.system.reliability.hostile_helpers import AttackPair, fuzz_arena_cfg, vectors

pytestmark = pytest.mark.timeout(600)

V2 = vectors(2)
INVALID = [bytes.fromhex(v["hex"]) for v in V2 if "hex" in v]
VALID = [bytes.fromhex(v["canonical_hex"]) for v in V2 if "canonical_hex" in v]
NUMBERS = st.sampled_from(
    [60.0, 30.0, 20.0, 15.0, 45.0, 0.0, -15.0, 1e308, math.nan, math.inf, 60, 15, 2**64 - 1,
     67.0, 100.0, 100.5, -0.0,
     True, None, "30", b"\x00", [30.0], {"hz": 30}]
)  # fmt: skip


@st.composite
def v2_client_message(draw: st.DrawFn) -> bytes:
    kinds = ["pose_rate", "forecast", "resync", "hello", "poses", "skeleton"]
    kind = draw(st.sampled_from(kinds))
    m: dict[str, Any] = {"type": kind}
    if kind == "pose_rate":
        m["rate_hz"] = draw(NUMBERS | st.floats())
    elif kind == "forecast":
        m["ms"] = draw(NUMBERS | st.floats())
    elif kind == "hello":  # a second hello: its fields are checked first, then ALREADY_JOINED
        m.update(version=2, token="t", room="r1", name="M", pose_rate_hz=draw(NUMBERS),
                 forecast_ms=draw(NUMBERS))  # fmt: skip
    elif kind == "poses":
        m.update(t=draw(st.floats()), data=draw(st.binary(max_size=600)))
    elif kind == "skeleton":
        m.update(player="p", handle=draw(st.integers(-5, 2**33)), skeleton=draw(st.binary()))
    if draw(st.booleans()):  # an unknown field, sometimes over the str bound
        m["x_future"] = draw(st.text(max_size=8) | st.just("y" * 4097))
    data: bytes = msgpack.packb(m, use_bin_type=True)
    cut = draw(st.sampled_from([None, None, None, 1, 3]))
    if cut is not None:
        data = data[:-cut]
    if draw(st.integers(0, 9)) == 0:  # over max_message_bytes: a client stays within it
        data = msgpack.packb({**m, "x_pad": "z" * 4000, "x_pad2": "z" * 4200}, use_bin_type=True)
    return data


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    with Arena(fuzz_arena_cfg()) as a:
        yield a


def test_v2_vectors_and_fuzz_get_their_codes_and_nobody_else_notices(arena: Arena) -> None:
    assert len(INVALID) >= 30 and len(VALID) >= 10
    before = errors_by_code(scrape(arena.port))

    def attack() -> AttackPair:
        fz = AttackPair(arena.port, version=2)
        try:
            for data in INVALID + VALID:
                for role in ("player", "backend"):
                    fz.send(role, data)

            checks = [HealthCheck.too_slow, HealthCheck.data_too_large]

            @settings(max_examples=150, deadline=None, derandomize=True, database=None,
                      suppress_health_check=checks)  # fmt: skip
            @given(st.sampled_from(["player", "backend"]), v2_client_message())
            def fuzz(role: str, data: bytes) -> None:
                fz.send(role, data)

            fuzz()
            return fz
        finally:
            fz.close()

    fz = as_attacker(attack)
    time.sleep(0.2)  # the last errors are counted before the scrape
    counted = delta(errors_by_code(scrape(arena.port)), before)
    print(f"v2 hostile: {fz.sent.total()} messages, errors {dict(fz.expected)}, {fz.joins} joins")
    assert counted == dict(fz.expected)  # every bad message counted, by its code
    assert {"BAD_FIELD", "OUT_OF_RANGE", "TOO_LARGE", "MALFORMED", "FORBIDDEN"} <= set(counted)
    assert http_get(arena.port, "/healthz")[0] == 200
    for player in arena.clients:
        assert arena.errors_of(player) == []
    assert arena.closed() == []
