"""Connection churn: clients that join, send garbage, are cut off and reconnect at once.

Each such cycle costs the server a WebSocket handshake, a token check, a join (welcome,
presence to the room) and a leave (presence again). The churner is a process of its
own rotating over eight loopback addresses (as a small botnet would), the healthy
players another, the server a third (:class:`~tests.system.reliability.arena.Arena`).

What protects the tick (``docs/reliability.md``, Churn): a client IP's fatal errors
spend its budget (``fatal_per_ip_per_min``), after which its connections are turned
away at the HTTP upgrade with 429, before the handshake; the node-wide accept rate
(``accepts_per_s``) caps what many addresses together can make the server do; and a
player enters the engine with its first frame, so a join that never streams costs the
engine thread nothing.

The node-wide rate is set here to a burst of every attempt the churner makes, so that
the per-address budgets, not it, decide who is turned away: with a smaller burst, a
churner fast enough (320 attempts in 0.4 s) empties the node's bucket before any address
has spent its budget, and no 429 is ever sent. The node-wide rate's 503 has its own test
(``tests/online/shell/test_http.py``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import pytest

from tests.online.conftest import make_cfg, token
from tests.system.reliability.arena import Arena, assert_rates_kept, delta, errors_by_code, scrape
from tests.system.reliability.flooder import run_flooder

pytestmark = pytest.mark.timeout(300)

FATAL_PER_MIN = 20  # the server default
IPS = 8
ATTEMPTS = 40  # per address: twice what its budget lets join
MAX_SECONDS = 60.0
ACCEPTS_PER_S = float(IPS * ATTEMPTS)  # the bucket's burst: every attempt (see above)


@pytest.fixture(scope="module")
def arena() -> Iterator[Arena]:
    cfg = make_cfg(lookahead=1, fatal_per_ip_per_min=FATAL_PER_MIN, accepts_per_s=ACCEPTS_PER_S)
    with Arena(cfg) as a:
        yield a


def _counter(port: int, name: str, **labels: str) -> float:
    return scrape(port).get((name, tuple(sorted(labels.items()))), 0.0)


def test_a_reconnecting_garbage_sender_is_turned_away_and_nobody_else_notices(
    arena: Arena,
) -> None:
    port = arena.port
    baseline = arena.baseline()
    errors_before = errors_by_code(scrape(port))
    turned_away_before = _counter(port, "posecast_connects_total", result="fatal_budget")
    with arena.window() as during:
        churner = run_flooder(
            port, token("r1", "churn"), "churn", MAX_SECONDS,
            "--ips", str(IPS), "--attempts", str(ATTEMPTS),
        )  # fmt: skip
        out, _ = churner.communicate(timeout=120)
    report = json.loads(out)
    time.sleep(0.2)  # the last errors are counted before the scrape
    errors = delta(errors_by_code(scrape(port)), errors_before)
    turned_away = _counter(port, "posecast_connects_total", result="fatal_budget")
    turned_away -= turned_away_before
    outcome = report["outcome"]
    print(
        f"churn: {report['attempts']} attempts in {report['seconds']:.1f} s from {IPS} "
        f"addresses: {outcome}; joins per address {sorted(report['joins_per_ip'].values())}; "
        f"server: {turned_away:.0f} turned away at the upgrade, errors {errors}"
    )
    # Each address spent its budget (a burst of FATAL_PER_MIN, refilling at
    # FATAL_PER_MIN a minute), then was turned away before any handshake: every
    # attempt that did not join got 429 (the node-wide rate, sized above, never cuts in
    # first: a 503 here would be counted, and the test would still add them up).
    refill = FATAL_PER_MIN * report["seconds"] / 60.0
    for ip, joins in report["joins_per_ip"].items():
        assert joins <= FATAL_PER_MIN + refill + 1, (ip, joins)
    assert report["attempts"] == IPS * ATTEMPTS, "the churner ran out of time"
    joined = sum(report["joins_per_ip"].values())
    assert outcome.get("http_429", 0) == turned_away > 0
    assert joined + turned_away + outcome.get("http_503", 0) == IPS * ATTEMPTS, outcome
    assert errors == {"MALFORMED": outcome["malformed"]}  # every garbage message counted
    for player in arena.clients:
        assert arena.errors_of(player) == []
    assert arena.closed() == []
    assert_rates_kept(during[0], baseline, "churn")
