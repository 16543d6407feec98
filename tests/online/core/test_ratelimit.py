"""Rate limits (posecast.online.core.ratelimit)."""

from __future__ import annotations

import pytest

from posecast.online.core.ratelimit import FatalBudget, IpLimiter, SocketCount, TokenBucket


def test_bucket_allows_the_rate_and_a_burst_then_refuses() -> None:
    b = TokenBucket(rate_hz=60, burst=5)
    assert all(b.allow(0.0) for _ in range(5))
    assert not b.allow(0.0)
    assert b.allow(1 / 60)  # one token back after one period
    assert not b.allow(1 / 60)


def test_bucket_sustains_exactly_its_rate() -> None:
    b = TokenBucket(rate_hz=60, burst=2)
    sent = sum(b.allow(i / 60) for i in range(600))
    assert sent == 600
    b2 = TokenBucket(rate_hz=60, burst=2)
    sent = sum(b2.allow(i / 120) for i in range(1200))  # twice the rate for 10 s
    assert 600 <= sent <= 603


def test_ip_limiter_slides_per_ip() -> None:
    lim = IpLimiter(per_minute=3)
    assert [lim.allow("a", t) for t in (0, 1, 2, 3)] == [True, True, True, False]
    assert lim.allow("b", 3)
    assert lim.allow("a", 60.5)  # the first attempt left the window


def test_ip_limiter_memory_is_bounded() -> None:
    lim = IpLimiter(per_minute=1, max_ips=10)
    for i in range(100):
        lim.allow(f"10.0.0.{i}", 0.0)
    assert len(lim._seen) == 10


def test_wait_s_paces_a_caller_to_the_rate() -> None:
    b = TokenBucket(rate_hz=10.0, burst=2.0)
    assert b.wait_s(0.0) == 0.0 and b.wait_s(0.0) == 0.0  # the burst
    assert b.wait_s(0.0) == pytest.approx(0.1)  # then one token per 1/rate
    assert b.wait_s(0.05) == pytest.approx(0.05)
    assert b.wait_s(0.1) == 0.0


def test_the_fatal_budget_turns_an_address_away_once_spent_and_refills() -> None:
    budget = FatalBudget(per_minute=3)
    assert not budget.exhausted("1.2.3.4", 0.0)
    for _ in range(3):
        budget.charge("1.2.3.4", 0.0)
    assert budget.exhausted("1.2.3.4", 0.0)
    assert not budget.exhausted("5.6.7.8", 0.0)  # another address is not affected
    assert budget.exhausted("1.2.3.4", 19.0)  # 3 a minute: one back after 20 s
    assert not budget.exhausted("1.2.3.4", 20.5)


def test_the_fatal_budget_forgets_the_least_recent_address_past_its_bound() -> None:
    budget = FatalBudget(per_minute=1, max_ips=2)
    for ip in ("a", "b", "c"):
        budget.charge(ip, 0.0)
    assert not budget.exhausted("a", 0.0) and budget.exhausted("c", 0.0)


def test_an_ipv6_host_is_one_address_per_64_and_mapped_ipv4_is_its_ipv4() -> None:
    budget = FatalBudget(per_minute=1)
    budget.charge("2001:db8:1:2::1", 0.0)
    assert budget.exhausted("2001:db8:1:2:ffff::9", 0.0)  # the same /64
    assert not budget.exhausted("2001:db8:1:3::1", 0.0)
    budget.charge("::ffff:192.0.2.7", 0.0)
    assert budget.exhausted("192.0.2.7", 0.0)


def test_take_runs_into_debt_and_says_how_long_it_takes_to_pay_back() -> None:
    b = TokenBucket(rate_hz=10.0, burst=5.0)
    assert b.take(0.0, 5) == 0.0  # the burst
    assert b.take(0.0, 20) == pytest.approx(2.0)  # 20 in debt at 10 a second
    assert b.take(1.0, 0) == pytest.approx(1.0)  # half paid back
    assert not b.allow(1.5)
    assert b.take(2.0, 1) == pytest.approx(0.1)


def test_socket_count_holds_per_address_and_forgets_an_address_with_none_open() -> None:
    count = SocketCount(2)
    assert count.open("10.0.0.1") and count.open("10.0.0.1")
    assert not count.open("10.0.0.1")  # a third at once
    assert count.open("10.0.0.2")  # another address has its own
    assert count.open("2001:db8::1") and count.open("2001:db8::2")  # one /64: one address
    assert not count.open("2001:db8::3")
    count.close("10.0.0.1")
    assert count.open("10.0.0.1")  # room for one again
    for ip in ("10.0.0.1", "10.0.0.1", "10.0.0.2", "2001:db8::1", "2001:db8::9"):
        count.close(ip)
    assert count._open == {}  # nothing kept for addresses with no socket open
