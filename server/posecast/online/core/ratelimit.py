"""Rate limits: a token bucket per connection; connection attempts, open sockets and fatal
errors per IP.

Both are pure: the caller passes the time (seconds, any monotonic clock).
"""

from __future__ import annotations

import ipaddress
from collections import OrderedDict, deque
from dataclasses import dataclass, field


def address_key(ip: str) -> str:
    """The unit a per-address limit counts: an IPv4 address, or an IPv6 address's /64
    (one host usually holds a whole /64, so rotating within it must not escape)."""
    try:
        addr = ipaddress.ip_address(ip)
    except ValueError:
        return ip
    if isinstance(addr, ipaddress.IPv6Address):
        if addr.ipv4_mapped is not None:
            return str(addr.ipv4_mapped)
        return str(ipaddress.IPv6Network((addr, 64), strict=False))
    return str(addr)


@dataclass
class TokenBucket:
    """``rate_hz`` tokens per second, at most ``burst`` saved up; one per message.

    A client sending at exactly its announced rate never runs dry, and network jitter
    that bunches up to ``burst`` frames is absorbed; a sustained excess is refused.
    """

    rate_hz: float
    burst: float
    tokens: float = -1.0  # starts full
    stamp: float | None = None

    def allow(self, now: float) -> bool:
        self._refill(now)
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False

    def wait_s(self, now: float) -> float:
        """Take a token if one is saved up (0.0); otherwise how long until one is.
        For pacing: a caller that waits that long and asks again gets one."""
        if self.allow(now):
            return 0.0
        return (1.0 - self.tokens) / self.rate_hz

    def take(self, now: float, n: int) -> float:
        """Take ``n`` tokens, into debt if there are fewer; the seconds until the debt is
        paid back (0.0 when there is none). For pacing what has already happened."""
        self._refill(now)
        self.tokens -= n
        return max(0.0, -self.tokens / self.rate_hz)

    def available(self, now: float) -> float:
        """The tokens saved up at ``now`` (negative: a debt), taking none."""
        self._refill(now)
        return self.tokens

    def _refill(self, now: float) -> None:
        if self.stamp is None:
            self.tokens, self.stamp = self.burst, now
        else:
            elapsed = max(0.0, now - self.stamp)
            self.tokens = min(self.burst, self.tokens + elapsed * self.rate_hz)
            self.stamp = now


@dataclass
class IpLimiter:
    """At most ``per_minute`` connection attempts per IP in any sliding 60 s window.

    Memory is bounded: at most ``max_ips`` addresses are tracked; the least recently
    seen is forgotten first (an attacker rotating addresses gains nothing from that
    which the per-IP limit would have stopped anyway).
    """

    per_minute: int
    max_ips: int = 65_536
    window_s: float = 60.0
    _seen: OrderedDict[str, deque[float]] = field(default_factory=OrderedDict)

    def allow(self, ip: str, now: float) -> bool:
        ip = address_key(ip)
        stamps = self._seen.pop(ip, None)
        if stamps is None:
            stamps = deque()
        while stamps and stamps[0] <= now - self.window_s:
            stamps.popleft()
        ok = len(stamps) < self.per_minute
        if ok:
            stamps.append(now)
        self._seen[ip] = stamps
        while len(self._seen) > self.max_ips:
            self._seen.popitem(last=False)
        return ok


@dataclass
class SocketCount:
    """At most ``per_ip`` sockets open at once per address (as :func:`address_key`
    counts it), counted from the TCP accept: a socket that connects and never sends a
    request holds one until the opening handshake times out, and the per-IP attempt
    rate, which the HTTP request reaches, never sees it. Memory: one entry per address
    with a socket open."""

    per_ip: int
    _open: dict[str, int] = field(default_factory=dict)

    def open(self, ip: str) -> bool:
        """Count a new socket from ``ip``; False (not counted) past the limit."""
        key = address_key(ip)
        n = self._open.get(key, 0)
        if n >= self.per_ip:
            return False
        self._open[key] = n + 1
        return True

    def close(self, ip: str) -> None:
        """A socket :meth:`open` counted has closed."""
        key = address_key(ip)
        n = self._open.get(key, 0) - 1
        if n > 0:
            self._open[key] = n
        else:
            self._open.pop(key, None)


@dataclass
class FatalBudget:
    """Fatal protocol errors per IP: ``per_minute`` of them, then that IP's new
    connections are refused until the budget refills (at ``per_minute / 60`` a second).

    A client that sends garbage, is cut off and reconnects at once makes the server do
    a handshake, a token check, a join and a leave each time, and tells the room
    twice; this makes the repeat offender cheap: it is turned away at the HTTP
    upgrade, before any of that. Only errors a conforming client never causes spend
    from it (not a timeout, a full room, a kick or being replaced: see
    :mod:`posecast.online.core.admission`).
    Memory is bounded like :class:`IpLimiter`'s.
    """

    per_minute: int
    max_ips: int = 65_536
    _buckets: OrderedDict[str, TokenBucket] = field(default_factory=OrderedDict)

    def charge(self, ip: str, now: float) -> None:
        """One fatal error from ``ip``."""
        ip = address_key(ip)
        bucket = self._buckets.pop(ip, None) or TokenBucket(self.per_minute / 60.0, self.per_minute)
        bucket.allow(now)
        self._buckets[ip] = bucket
        while len(self._buckets) > self.max_ips:
            self._buckets.popitem(last=False)

    def exhausted(self, ip: str, now: float) -> bool:
        """Whether ``ip`` has spent its budget (its connections are refused)."""
        bucket = self._buckets.get(address_key(ip))
        if bucket is None or bucket.stamp is None:
            return False
        tokens = min(bucket.burst, bucket.tokens + max(0.0, now - bucket.stamp) * bucket.rate_hz)
        return tokens < 1.0
