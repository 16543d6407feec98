"""Clock sync: the NTP formulas, picking the sample with the smallest rtt, and the
display clock (the shared table proto/vectors/sdk/clock.json)."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest

from posecast_client.clock import ClockSync

TABLE = Path(__file__).resolve().parents[3] / "proto" / "vectors" / "sdk" / "clock.json"
CASES = [c["name"] for c in json.loads(TABLE.read_text("utf-8"))["cases"]] if TABLE.exists() else []


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


def test_display_time_follows_to_server_until_a_pong_and_snaps_on_the_first() -> None:
    clock = ClockSync()
    assert clock.display_time(3.0) == 3.0 == clock.to_server(3.0)  # to_server's convention
    assert clock.display_offset_s is None
    exchange(clock, 4.0, offset=250.0, up=0.01, down=0.01)
    assert clock.display_time(4.5) == clock.to_server(4.5)


def test_display_time_slews_an_estimate_step_and_never_goes_back() -> None:
    clock = ClockSync()
    exchange(clock, 1.0, offset=50.0, up=0.030, down=0.002)  # 14 ms too late
    frames = [2.0 + k / 90 for k in range(90 * 10)]
    shown = [clock.display_time(frames[0])]
    exchange(clock, 2.0, offset=50.0, up=0.001, down=0.029)  # better: a -28 ms step
    assert clock.offset_s is not None and clock.to_server(2.0) - shown[0] < -0.027
    shown += [clock.display_time(t) for t in frames[1:]]
    steps = [b - a for a, b in itertools.pairwise(shown)]
    assert min(steps) >= (1 - 0.005) / 90 - 1e-9 and max(steps) <= 1 / 90 + 1e-9
    assert shown[-1] == pytest.approx(clock.to_server(frames[-1]), abs=1e-12)  # 5.6 s later
    assert shown[90] == pytest.approx(clock.to_server(frames[90]) + 0.028 - 0.005, abs=1e-6)


def test_display_time_snaps_beyond_snap_s_and_reset_forgets_it() -> None:
    clock = ClockSync(snap_s=0.05)
    exchange(clock, 1.0, offset=7.0, up=0.01, down=0.01)
    clock.display_time(1.5)
    exchange(clock, 2.0, offset=7.06, up=0.001, down=0.001)  # the server's clock stepped
    assert clock.display_time(2.5) == clock.to_server(2.5)
    before = clock.display_time(2.6)
    assert clock.display_time(2.4) == pytest.approx(before - 0.2)  # earlier: no slew
    clock.reset()
    assert clock.display_offset_s is None and clock.display_time(3.0) == 3.0
    exchange(clock, 3.0, offset=-5.0, up=0.01, down=0.01)
    assert clock.display_time(3.1) == clock.to_server(3.1)


def test_display_clock_options_are_checked() -> None:
    for bad in ({"slew_rate": -0.1}, {"slew_rate": 1.0}, {"snap_s": -1.0}):
        with pytest.raises(ValueError):
            ClockSync(**bad)  # type: ignore[arg-type]


@pytest.mark.skipif(not TABLE.exists(), reason="proto/vectors not found (repo only)")
@pytest.mark.parametrize("name", CASES)
def test_clock_table(name: str) -> None:
    """proto/vectors/sdk/clock.json, as the TypeScript and C# SDKs run it."""
    table = json.loads(TABLE.read_text("utf-8"))
    case = next(c for c in table["cases"] if c["name"] == name)
    clock = ClockSync(**case["config"])
    tol = table["tolerance"]
    for k, step in enumerate(case["steps"]):
        if "reset" in step:
            clock.reset()
        elif "add" in step:
            assert clock.add(*step["add"]) is not None, k
            assert clock.offset_s == pytest.approx(step["offset_s"], abs=tol), k
        else:
            want = step["display"] if step["expect"] is None else step["expect"]
            assert clock.display_time(step["display"]) == pytest.approx(want, abs=tol), k
