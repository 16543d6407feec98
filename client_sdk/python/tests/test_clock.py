"""Clock sync: the NTP formulas, and picking the sample with the smallest rtt."""

from __future__ import annotations

import pytest

from posecast_client.clock import ClockSync


def exchange(clock: ClockSync, t0: float, offset: float, up: float, down: float) -> None:
    """One ping/pong: ``offset`` = server - client, ``up``/``down`` one-way delays."""
    t1 = t0 + up + offset
    t2 = t1 + 0.0001  # server processing
    t3 = t2 - offset + down
    clock.add(t0, t1, t2, t3)


def test_symmetric_delays_give_the_exact_offset() -> None:
    clock = ClockSync()
    assert clock.offset_s is None and clock.to_server(5.0) == 5.0
    exchange(clock, 10.0, offset=1234.5, up=0.02, down=0.02)
    assert clock.offset_s == pytest.approx(1234.5, abs=1e-9)
    assert clock.rtt_s == pytest.approx(0.04, abs=1e-9)
    assert clock.to_server(11.0) == pytest.approx(1245.5)
    assert clock.to_client(1245.5) == pytest.approx(11.0)


def test_the_smallest_rtt_wins_and_its_error_is_at_most_half_of_it() -> None:
    clock = ClockSync(window=4)
    exchange(clock, 1.0, offset=-3.0, up=0.100, down=0.010)  # asymmetric, slow
    exchange(clock, 2.0, offset=-3.0, up=0.004, down=0.002)  # the good one
    exchange(clock, 3.0, offset=-3.0, up=0.050, down=0.080)
    best = clock.best
    assert best is not None and best.rtt_s == pytest.approx(0.006, abs=1e-9)
    assert abs(best.offset_s + 3.0) <= best.rtt_s / 2
    for k in range(4):  # the good sample falls out of the window
        exchange(clock, 10.0 + k, offset=-3.0, up=0.03, down=0.03)
    assert clock.rtt_s == pytest.approx(0.06, abs=1e-9)


def test_absurd_exchanges_are_ignored_and_reset_forgets() -> None:
    clock = ClockSync()
    assert clock.add(5.0, 1.0, 1.0, 4.0) is None  # the pong came back before the ping left
    assert clock.offset_s is None
    exchange(clock, 1.0, offset=2.0, up=0.01, down=0.01)
    clock.reset()
    assert clock.best is None
