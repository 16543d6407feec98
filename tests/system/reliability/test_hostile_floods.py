"""Floods from one client address: messages (frames, pings, junk) and connections.

The server runs with the default rate limits (``max_rate_hz`` 120 with a burst of
30, ``control_rate_hz`` 20, ``error_rate_hz`` 20) and ``conn_per_ip_per_min`` 30.
The healthy players of the :class:`Arena` connect from 127.0.0.1; the flooders from
127.0.0.2 (messages: a separate process, so its CPU is not charged to the server's
event loop) and 127.0.0.3 (connections). The limits must engage, the flooder must get
the stable code, everything must be counted in ``/metrics``, and the healthy pose
streams must keep their rate.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import pytest
from websockets.exceptions import InvalidStatus

from posecast.online.protocol.messages import Error, Message, Welcome
from tests.online.conftest import make_cfg, token
from tests.system.reliability.arena import Arena, assert_rates_kept, delta, errors_by_code, scrape
from tests.system.reliability.flooder import as_attacker, run_flooder
from tests.system.reliability.hostile_helpers import Attacker

pytestmark = pytest.mark.timeout(120)
FLOOD_S = 1.0
CONN_PER_MIN = 30


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    cfg = make_cfg(lookahead=1, conn_per_ip_per_min=CONN_PER_MIN, hello_timeout_s=1.0)
    with Arena(cfg) as a:
        yield a


def _counter(port: int, name: str, **labels: str) -> float:
    return scrape(port).get((name, tuple(sorted(labels.items()))), 0.0)


@pytest.mark.parametrize("kind", ["frames", "pings", "junk"])
def test_a_message_flood_is_limited_and_nobody_else_notices(arena: Arena, kind: str) -> None:
    cfg = arena.cfg
    baseline = arena.baseline()
    before = scrape(arena.port)
    t0 = time.monotonic()
    with arena.window() as during:
        proc = run_flooder(arena.port, token("r1", f"flood-{kind}"), kind, FLOOD_S)
        out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0
    report = json.loads(out)
    time.sleep(0.3)
    after = scrape(arena.port)
    counted = delta(errors_by_code(after), errors_by_code(before))
    sent, seconds, replies = report["sent"], report["seconds"], report["errors"]
    # The flooder's close handshake waits for the server to read everything it sent,
    # so all of the flood was handled between t0 and now (the server lags the sender).
    window_s = time.monotonic() - t0
    print(f"{kind} flood: {sent} messages in {seconds:.1f} s ({sent / seconds:.0f}/s); "
          f"error replies {replies}; counted {counted}")  # fmt: skip
    budget = cfg.error_rate_hz * window_s + cfg.error_rate_hz  # replies: rate plus burst
    # Read pacing: the server decodes at most twice the protocol's rates from one
    # connection and leaves the rest unread on the flooder's side; a flooder that stops
    # reading its replies meanwhile is cut off as SLOW_CONSUMER, and what it sent but
    # the server had not read when it left or was cut off is never handled (nor does
    # it hold the event loop).
    paced_hz = 2.0 * (cfg.max_rate_hz + cfg.control_rate_hz)
    paced_burst = 2.0 * (cfg.rate_burst + cfg.control_rate_hz)
    handled = sum(v for k, v in counted.items() if k != "SLOW_CONSUMER")
    if kind != "frames":  # (accepted frames are not errors: see below for those)
        assert handled <= paced_hz * window_s + paced_burst, "reads were not paced"
    paced = after.get(("posecast_reads_paced_total", ()), 0) - before.get(
        ("posecast_reads_paced_total", ()), 0
    )
    assert paced >= 1
    # A flooder held back by its read budget for 2 s on end is cut off with one fatal
    # RATE_LIMITED (shell/paced.py), counted in posecast_floods_cut_off_total.
    cut = after.get(("posecast_floods_cut_off_total", ()), 0) - before.get(
        ("posecast_floods_cut_off_total", ()), 0
    )
    assert cut <= 1
    print(f"{kind} flood: handled {handled:.0f} of {sent} over {window_s:.1f} s; "
          f"paused reading {paced:.0f} times")  # fmt: skip
    if kind == "junk":  # UNKNOWN_TYPE: non-fatal, dropped; every handled one counted
        assert set(counted) <= {"UNKNOWN_TYPE", "SLOW_CONSUMER", "RATE_LIMITED"}
        assert counted.get("SLOW_CONSUMER", 0) + cut <= 1
        assert counted.get("RATE_LIMITED", 0) == cut
        # What was read was counted; what the flooder sent past the pace was never
        # read (it left, or was cut off as SLOW_CONSUMER, with it still unread).
        assert 1 <= counted["UNKNOWN_TYPE"] <= sent
        assert 1 <= replies["UNKNOWN_TYPE"] <= budget
    else:
        limit_hz, burst = (
            (cfg.max_rate_hz, cfg.rate_burst) if kind == "frames" else (cfg.control_rate_hz,) * 2
        )
        # The flooder may itself be cut off as SLOW_CONSUMER (it hardly reads while it
        # sends): fair, and then what it sent after the cut was never handled.
        assert set(counted) <= {"RATE_LIMITED", "SLOW_CONSUMER"}
        assert counted.get("SLOW_CONSUMER", 0) + cut <= 1
        # The limit engaged: of what the server read (paced), all but the rate and
        # the burst was refused. (What it never read cannot be counted either way.)
        refused = counted.get("RATE_LIMITED", 0)
        assert refused >= 1, "the limit did not engage"
        print(f"{kind} flood: {refused:.0f} refused (limit {limit_hz} Hz, burst {burst})")
        assert 1 <= replies["RATE_LIMITED"] <= budget
        if kind == "frames":
            dropped = delta(
                {"rate": after.get(("posecast_frames_dropped_total", (("reason", "rate"),)), 0)},
                {"rate": before.get(("posecast_frames_dropped_total", (("reason", "rate"),)), 0)},
            )
            assert dropped == {"rate": counted["RATE_LIMITED"] - cut}
    for player in arena.clients:
        assert arena.errors_of(player) == []
    assert_rates_kept(during[0], baseline, f"{kind} flood")


def test_a_connection_flood_gets_429_and_others_still_join(arena: Arena) -> None:
    """100 connection attempts from one address in a burst: 30 get in (and, sending no
    ``hello``, are timed out with TIMED_OUT), 70 get HTTP 429; a player from another
    address still joins, and the healthy streams keep their rate."""
    baseline = arena.baseline()
    refused0 = _counter(arena.port, "posecast_connects_total", result="rate_limited")
    accepted0 = _counter(arena.port, "posecast_connects_total", result="accepted")
    timed_out0 = errors_by_code(scrape(arena.port)).get("TIMED_OUT", 0.0)
    idle: list[Attacker] = []
    statuses: list[int] = []

    def attack() -> tuple[Attacker, list[Message]]:
        for _ in range(100):
            try:
                idle.append(Attacker(arena.port, source_ip="127.0.0.3"))
                statuses.append(101)
            except InvalidStatus as exc:
                statuses.append(exc.response.status_code)
        late = Attacker(arena.port)  # another address: its own budget
        assert isinstance(late.hello(token("r2", "late"), room="r2"), Welcome)
        errors = [att.next(lambda m: isinstance(m, Error), timeout_s=5) for att in idle]
        time.sleep(0.5)
        return late, errors

    with arena.window() as during:
        late, errors = as_attacker(attack)
    assert statuses == [101] * CONN_PER_MIN + [429] * (100 - CONN_PER_MIN)
    assert {(e.code, e.fatal) for e in errors if isinstance(e, Error)} == {("TIMED_OUT", True)}
    assert all(isinstance(e, Error) for e in errors)
    refused = _counter(arena.port, "posecast_connects_total", result="rate_limited") - refused0
    accepted = _counter(arena.port, "posecast_connects_total", result="accepted") - accepted0
    timed_out = errors_by_code(scrape(arena.port)).get("TIMED_OUT", 0.0) - timed_out0
    assert (refused, accepted, timed_out) == (100 - CONN_PER_MIN, CONN_PER_MIN + 1, CONN_PER_MIN)
    late.close()
    for att in idle:
        att.close()
    for player in arena.clients:
        assert arena.errors_of(player) == []
    assert_rates_kept(during[0], baseline, "connection flood")
