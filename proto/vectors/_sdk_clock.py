"""``proto/vectors/sdk/clock.json``: ``ClockSync``'s display clock (``display_time``;
``docs/game-engines.md``, "Interpolation").

Each case is a config and a list of steps: an exchange added (its four times and the
estimate after it), a display query (a client time and the display time expected
then, ``null`` before the first pong: Python and C# return the client time there,
TypeScript throws), or a reset. The expected values are the Python SDK's own
(``posecast_client.clock``): the rules are short, and this pins the other SDKs to it;
each query also names the rule it exercises, and every rule is checked to occur.
"""

from __future__ import annotations

from typing import Any

from posecast_client.clock import ClockSync

CLOCK_DEFAULTS = {"window": 8, "slew_rate": 0.005, "snap_s": 0.1}
CLOCK_RULES = {"before_pong", "snap", "slew", "slew_reaches", "steady", "earlier_time"}


def ex(t0: float, up: float, down: float, offset: float) -> dict[str, Any]:
    """One ping/pong: ``offset`` = server - client, ``up``/``down`` the one-way delays,
    the server holding the ping 0.2 ms. Its offset is wrong by ``(up - down) / 2``."""
    t1 = t0 + up + offset
    t2 = t1 + 0.0002
    t3 = t2 - offset + down
    return {"add": [round(t, 9) for t in (t0, t1, t2, t3)]}


def show(t: float) -> dict[str, Any]:
    return {"display": round(t, 9)}


def clock_case(name: str, description: str, steps: list[Any], **cfg: Any) -> dict[str, Any]:
    """Run ``steps`` on the Python SDK's ``ClockSync``, naming each query's rule."""
    config = {**CLOCK_DEFAULTS, **cfg}
    clock = ClockSync(**config)
    out: list[dict[str, Any]] = []
    latest: float | None = None
    for step in steps:
        if "reset" in step:
            clock.reset()
            latest = None
            out.append({"reset": True})
        elif "add" in step:
            assert clock.add(*step["add"]) is not None, (name, step)
            out.append({"add": step["add"], "offset_s": clock.offset_s})
        else:
            t, before, est = step["display"], clock.display_offset_s, clock.offset_s
            shown = clock.display_time(t)
            after = clock.display_offset_s
            if est is None:
                rule, expect = "before_pong", None
            elif before is None or abs(est - before) > config["snap_s"]:
                rule, expect = "snap", shown
                assert after == est
            elif latest is not None and t < latest:
                rule, expect = "earlier_time", shown
                assert after == before
            elif before == est:
                rule, expect = "steady", shown
            else:
                rule, expect = ("slew_reaches" if after == est else "slew"), shown
                assert (
                    after is not None
                    and abs(after - before) <= config["slew_rate"] * (t - (latest or t)) + 1e-12
                )
            latest = t if latest is None else max(latest, t)
            out.append({"display": t, "expect": expect, "rule": rule})
    return {"name": name, "description": description, "config": config, "steps": out}


def clock_cases() -> list[dict[str, Any]]:
    off = 1000.0
    frames = [show(12.05 + k / 90) for k in range(3)]
    return [
        clock_case(
            "slew_snap_reset",
            "default config; server = client + 1000 s. A first pong 14 ms off snaps; a "
            "better one 14 ms off the other way steps the estimate by -28 ms, which the "
            "display clock slews out at 5 ms/s (a query at an earlier time moves "
            "nothing); a 14 ms better sample slews back; the server's clock stepping by "
            "0.3 s snaps; after a reset nothing until a pong, then a snap onto a new "
            "server (offset -50 s)",
            [
                show(10.0),
                ex(10.0, 0.030, 0.002, off),
                show(10.1),
                show(10.1 + 1 / 90),
                ex(12.0, 0.001, 0.029, off),
                *frames,
                show(12.04),
                show(12.05 + 3 / 90),
                show(20.0),
                show(20.0 + 1 / 90),
                ex(20.5, 0.002, 0.002, off),
                show(20.6),
                show(20.6 + 1 / 90),
                ex(22.0, 0.001, 0.001, off + 0.3),
                show(22.05),
                show(22.05 + 1 / 90),
                {"reset": True},
                show(23.0),
                ex(24.0, 0.005, 0.005, -50.0),
                show(24.1),
                show(24.1 + 1 / 90),
            ],
        ),
        clock_case(
            "window_evicts_the_best",
            "window 3, slew 1 %, snap 0.05 s; server = client + 12.5 s. The 2 ms "
            "sample leaves the window after three more: the estimate steps by -6 ms and "
            "is slewed out at 10 ms/s; then the server's clock steps by 76 ms, beyond "
            "snap_s",
            [
                ex(0.0, 0.001, 0.001, 12.5),
                show(0.1),
                ex(2.0, 0.020, 0.004, 12.5),
                ex(4.0, 0.004, 0.016, 12.5),
                show(4.1),
                show(5.9),
                ex(6.0, 0.030, 0.010, 12.5),
                show(6.1),
                show(6.2),
                show(6.3),
                show(6.4),
                show(6.5),
                ex(8.0, 0.001, 0.001, 12.576),
                show(8.1),
                show(8.2),
            ],
            window=3,
            slew_rate=0.01,
            snap_s=0.05,
        ),
    ]


def clock() -> dict[str, Any]:
    cases = clock_cases()
    rules = {s["rule"] for c in cases for s in c["steps"] if "rule" in s}
    assert rules == CLOCK_RULES, rules
    return {
        "description": "ClockSync's display clock (docs/game-engines.md, Interpolation): run "
        "the steps in order on one ClockSync with the case's config; after each add the "
        "estimate is offset_s, each display query returns expect within tolerance "
        "(null: before the first pong, each SDK's to_server convention); rule names "
        "the rule the query exercises",
        "tolerance": 1e-9,
        "cases": cases,
    }
