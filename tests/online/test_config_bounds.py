"""The range of every numeric server setting (online.config_bounds): what a range holds,
how the errors and ``--help`` write it, and the protocol limits' ranges taken from the
protocol (that ``ServerConfig`` checks each value against it is ``test_config.py``'s)."""

from __future__ import annotations

import math

import pytest

from posecast.online.config_bounds import BOUNDS, MAX_SNDBUF_BYTES, Bounds
from posecast.online.engine.config import MAX_SAMPLES
from posecast.online.engine.ports import MAX_THREADS
from posecast.online.protocol.messages import LIMIT_RANGES


def test_a_range_holds_its_ends_unless_its_low_end_is_excluded() -> None:
    closed, above = Bounds(1, 4096), Bounds(0, 300, above=True, unit="seconds")
    assert closed.holds(1) and closed.holds(4096) and not closed.holds(0.999)
    assert not closed.holds(4096.5)
    assert not above.holds(0) and above.holds(1e-9) and above.holds(300)
    assert not above.holds(300.0001)
    for b in (closed, above):
        assert not b.holds(math.nan) and not b.holds(math.inf) and not b.holds(-math.inf)


@pytest.mark.parametrize(
    ("bounds", "interval", "words"),
    [
        (Bounds(1, 4096), "[1, 4096]", "1 to 4096"),
        (Bounds(0, 300, above=True, unit="seconds"), "(0, 300] seconds", "above 0, up to 300"),
        (Bounds(0, 1), "[0, 1]", "0 to 1"),
        (Bounds(1, 1_000_000), "[1, 1000000]", "1 to 1,000,000"),
        (Bounds(0, 99_999), "[0, 99999]", "0 to 99999"),  # commas from six digits on
        (Bounds(0.5, 2.25), "[0.5, 2.25]", "0.5 to 2.25"),
    ],
)
def test_a_range_is_written_for_errors_and_for_help(
    bounds: Bounds, interval: str, words: str
) -> None:
    assert bounds.interval() == interval
    assert bounds.words() == words


def test_every_bound_is_finite_and_the_tables_shared_tops_are_the_sources() -> None:
    for name, b in BOUNDS.items():
        assert math.isfinite(b.low) and math.isfinite(b.high) and b.low < b.high, name
    assert (BOUNDS["samples"].low, BOUNDS["samples"].high) == (1, MAX_SAMPLES)
    assert BOUNDS["engine_threads"].high == MAX_THREADS
    assert BOUNDS["socket_sndbuf_bytes"].high == MAX_SNDBUF_BYTES == 2**31 - 1
    for setting, limit in {
        "max_message_bytes": "max_message_bytes",
        "max_rate_hz": "max_rate_hz",
        "max_players_per_room": "max_players",
        "max_watch_rooms": "max_watch_rooms",
    }.items():
        b = BOUNDS[setting]
        assert (b.low, b.high) == tuple(LIMIT_RANGES[limit])[:2], setting
    # a time or a rate of 0 would stop what it times: those exclude their low end
    timed = [n for n, b in BOUNDS.items() if b.unit == "seconds"]
    assert len(timed) > 5
    assert [n for n in timed if not BOUNDS[n].above] == ["token_keys_reload_s"]  # 0: SIGHUP only
