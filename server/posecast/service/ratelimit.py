"""Rate limits: a token bucket per connection, and connection attempts per IP.

Both are pure: the caller passes the time (seconds, any monotonic clock).
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass, field


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
        if self.stamp is None:
            self.tokens, self.stamp = self.burst, now
        else:
            elapsed = max(0.0, now - self.stamp)
            self.tokens = min(self.burst, self.tokens + elapsed * self.rate_hz)
            self.stamp = now
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
