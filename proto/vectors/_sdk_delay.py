"""``proto/vectors/sdk/delay.json``: the adaptive render delay of ``PoseBuffer``
(``posecast_client.render_delay``, ``docs/game-engines.md``, "The render delay").

Each case is a buffer config and a timeline: pushes (a pose's ``seq`` and server time
``t``, in the order the link delivers them) and 90 Hz display queries, each with the
delay, the target, the shown time ``t`` and the rule (interpolate, extrapolate,
hold) expected then. The arrival sequences are seeded simulations of a link: clean
loopback, the reliability suite's jittery relay, stalls that release bursts, loss,
jitter that comes and goes, a link beyond the bound, a clock running ahead, and the
fixed delay.

The expected values come from :class:`DelayReference`, the rules written again here
on plain lists (the whole window sorted at each query, modes from the arrived poses'
times); :func:`delay_case` asserts that the Python SDK's ``PoseBuffer`` gives the same
trajectory, then the TypeScript and C# SDKs replay it.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
from posecast_client.interp import InterpConfig, PoseBuffer
from posecast_client.protocol import Pose

POSE_HZ, DISPLAY_HZ = 60.0, 90.0
T0 = 100.0  # server time of the first pose
START = T0 + 0.05  # the first display query
# InterpConfig's fields, with its defaults: every case names every knob.
DELAY_DEFAULTS: dict[str, Any] = {
    "delay_s": 0.1,
    "max_extrapolate_s": 0.1,
    "teleport_m": 1.0,
    "gap_s": 0.25,
    "capacity": 32,
    "correction_s": 0.05,
    "adaptive": True,
    "min_delay_s": 0.02,
    "max_delay_s": 0.25,
    "delay_quantile": 0.99,
    "delay_window": 256,
    "delay_margin_s": 0.002,
    "delay_slew": 0.05,
}


class DelayReference:
    """The render delay and the rule each frame takes, from the rules, on lists."""

    def __init__(self, cfg: dict[str, Any]) -> None:
        self.cfg = cfg
        self.poses: list[list[Any]] = []  # [t, seen], sorted by t
        self.needs: list[float] = []  # in arrival order, all of them
        self.delay = min(max(cfg["delay_s"], cfg["min_delay_s"]), cfg["max_delay_s"])
        self.time: float | None = None

    def push(self, t: float) -> bool:
        ts = [p[0] for p in self.poses]
        if t in ts or (len(ts) >= self.cfg["capacity"] and t < min(ts)):
            return False
        self.poses = sorted([*self.poses, [t, False]])[-self.cfg["capacity"] :]
        return True

    def target(self) -> float | None:
        window = sorted(self.needs[-self.cfg["delay_window"] :])
        if not window:
            return None
        rank = math.ceil(self.cfg["delay_quantile"] * len(window))
        q = window[min(len(window), max(1, rank)) - 1]
        lo, hi = self.cfg["min_delay_s"], self.cfg["max_delay_s"]
        return min(max(q + self.cfg["delay_margin_s"], lo), hi)

    def query(self, time: float) -> dict[str, Any] | None:
        cfg = self.cfg
        if cfg["adaptive"]:
            measures = self.time is not None and 0 <= time - self.time <= cfg["gap_s"]
            for k, p in enumerate(self.poses):
                if not p[1]:
                    p[1] = True
                    if measures and k > 0 and p[0] - self.poses[k - 1][0] <= cfg["gap_s"]:
                        self.needs.append(time - self.poses[k - 1][0])
            target = self.target()
            if self.time is not None and time > self.time and target is not None:
                step = cfg["delay_slew"] * (time - self.time)
                if abs(target - self.delay) <= step:
                    self.delay = target
                else:
                    self.delay += step if target > self.delay else -step
            self.time = time if self.time is None else max(self.time, time)
            delay = self.delay
        else:
            target, delay = None, cfg["delay_s"]
        if not self.poses:
            return None
        tau = time - delay
        ts = [p[0] for p in self.poses]
        before = [t for t in ts if t <= tau]
        after = [t for t in ts if t > tau]
        if not before:
            mode = "hold"
        elif after and after[0] - before[-1] <= cfg["gap_s"]:
            mode = "interpolate"
        elif len(before) < 2 or before[-1] - before[-2] > cfg["gap_s"]:
            mode = "hold"
        else:
            mode = "extrapolate" if tau - before[-1] <= cfg["max_extrapolate_s"] else "hold"
        return {"delay_s": delay, "target_s": target, "t": tau, "mode": mode}


def pose(seq: int, t: float) -> Pose:
    """One joint moving along +X at 1 m/s: the poses' content does not matter here."""
    return Pose("p", seq, t, np.array([[t - T0, 1.0, 0.0]]))


def timeline(arrive: np.ndarray, seconds: float, back_at: float | None = None) -> list[Any]:
    """Pushes at their arrival (``inf``: lost) and 90 Hz queries, merged in time order;
    a push and a query at the same moment: the push first. ``back_at``: one query
    there is repeated 30 ms earlier (time going back)."""
    events: list[tuple[float, int, Any]] = []
    for k, a in enumerate(arrive):
        if np.isfinite(a):
            events.append((float(a), 0, {"push": [k, round(T0 + k / POSE_HZ, 9)]}))
    for f in range(int(seconds * DISPLAY_HZ)):
        now = round(START + f / DISPLAY_HZ, 9)
        events.append((now, 1, {"query": now}))
        if back_at is not None and abs(now - back_at) < 0.5 / DISPLAY_HZ:
            events.append((now, 2, {"query": round(now - 0.03, 9)}))
    events.sort(key=lambda e: (e[0], e[1]))
    return [e[2] for e in events]


def delay_case(name: str, description: str, steps: list[Any], **cfg: Any) -> dict[str, Any]:
    """Run ``steps`` on the reference and on the Python SDK's buffer; they agree."""
    config = {**DELAY_DEFAULTS, **cfg}
    ref, buf = DelayReference(config), PoseBuffer(InterpConfig(**config))
    out: list[Any] = []
    for step in steps:
        if "push" in step:
            seq, t = step["push"]
            assert ref.push(t) == buf.push(pose(seq, t)), (name, step)
            out.append(step)
            continue
        want, got = ref.query(step["query"]), buf.pose_at(step["query"])
        if want is None:
            assert got is None, (name, step)
            out.append({"query": step["query"], "expect": None})
            continue
        assert got is not None and got.mode == want["mode"], (name, step, got, want)
        assert got.t == want["t"] and buf.delay_s == want["delay_s"], (name, step)
        assert buf.target_delay_s == want["target_s"], (name, step)
        expect = {k: (v if not isinstance(v, float) else round(v, 12)) for k, v in want.items()}
        out.append({"query": step["query"], "expect": expect})
    return {"name": name, "description": description, "config": config, "steps": out}


def link(n: int, seed: int, *, latency: float, hold: float, drop: float = 0.0) -> np.ndarray:
    """Arrival times of ``n`` 60 Hz poses: ``latency`` plus a uniform ``0..hold``
    each (so they overtake each other), a share ``drop`` lost (``inf``); seeded."""
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n) / POSE_HZ
    arrive = t + latency + rng.uniform(0.0, hold, size=n)
    arrive[rng.random(n) < drop] = np.inf
    return arrive


def delay_cases() -> list[dict[str, Any]]:
    n = int(6 * POSE_HZ)
    t = T0 + np.arange(n) / POSE_HZ
    stalls = t + 0.002
    for k in range(n):  # 0.2 s stalls every second: held, then released at once
        phase = (t[k] - T0) % 1.0
        if 0.5 <= phase < 0.7:
            stalls[k] = T0 + math.floor(t[k] - T0) + 0.7 + 0.002
    comes_and_goes = link(n, 5, latency=0.002, hold=0.001)
    middle = (t >= T0 + 1.5) & (t < T0 + 2.5)
    comes_and_goes[middle] = link(n, 6, latency=0.005, hold=0.060)[middle]
    return [
        delay_case(
            "clean_loopback",
            "60 Hz poses arriving 1-2 ms after their tick (loopback): from the 0.1 s "
            "start the delay slews down at 5 % to about one pose interval plus a frame",
            timeline(link(n, 1, latency=0.001, hold=0.001), 3.0),
        ),
        delay_case(
            "jittery_relay",
            "5 ms latency plus a uniform 0-40 ms hold per pose (the reliability suite's "
            "relay): poses overtake each other; the delay settles near the worst need",
            timeline(link(n, 2, latency=0.005, hold=0.040), 3.0),
        ),
        delay_case(
            "bursty",
            "2 ms latency, but every second the link stalls 0.2 s and then delivers "
            "the held poses at once: the delay climbs at 5 % toward the stall's need",
            timeline(stalls, 3.0),
        ),
        delay_case(
            "lossy_relay",
            "the relay's jitter with 20 % of poses lost: a lost pose doubles its "
            "successor's interval, which the need includes",
            timeline(link(n, 3, latency=0.005, hold=0.040, drop=0.2), 3.0),
        ),
        delay_case(
            "jitter_comes_and_goes",
            "a 64-pose window: clean, then 60 ms of jitter for 1 s, then clean again; "
            "the delay rises and falls again, 50 ms per second at most; one query "
            "repeated 30 ms earlier (time going back) moves nothing",
            timeline(comes_and_goes, 5.0, back_at=START + 2.0),
            delay_window=64,
        ),
        delay_case(
            "bounded_above",
            "0.4 s of jitter with max_delay_s 0.15: the target stops at the bound and "
            "frames past the newest pose extrapolate",
            timeline(link(n, 4, latency=0.005, hold=0.4), 3.0),
            max_delay_s=0.15,
        ),
        delay_case(
            "bounded_below",
            "the display clock runs 30 ms ahead of the server's (poses seem to arrive "
            "before their tick): the target stops at min_delay_s 0.025, slew 0.1",
            timeline(link(n, 7, latency=-0.030, hold=0.001), 2.0),
            min_delay_s=0.025,
            delay_slew=0.1,
        ),
        delay_case(
            "fixed_delay",
            "adaptive off: the relay's jitter shown at the fixed delay_s 0.1 throughout",
            timeline(link(n, 2, latency=0.005, hold=0.040), 2.0),
            adaptive=False,
        ),
    ]


def render_delay_table() -> str:
    """The table as JSON, one step per line (a case has hundreds)."""
    table = delay_table()
    head = {k: v for k, v in table.items() if k != "cases"}
    lines = ["{", *(f" {json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()), ' "cases": [']
    for i, case in enumerate(table["cases"]):
        lines.append("  {")
        lines += [f"   {json.dumps(k)}: {json.dumps(case[k])}," for k in ("name", "description")]
        lines.append(f'   "config": {json.dumps(case["config"])},')
        lines.append('   "steps": [')
        steps = [json.dumps(s, separators=(",", ":")) for s in case["steps"]]
        lines.append(",\n".join(f"    {s}" for s in steps))
        lines.append("   ]")
        lines.append("  }" + ("," if i < len(table["cases"]) - 1 else ""))
    lines += [" ]", "}"]
    return "\n".join(lines) + "\n"


def delay_table() -> dict[str, Any]:
    return {
        "description": "PoseBuffer's adaptive render delay (docs/game-engines.md, The "
        "render delay): run the steps in order on one buffer with the case's config, "
        "pushing a pose with one joint at [t - 100, 1, 0] and no rotations for each push "
        "[seq, t]; each query is pose_at(query): expect null (no pose yet) or the "
        "delay, the target (null: none yet), the shown t and its mode, within tolerance",
        "tolerance": 1e-9,
        "cases": delay_cases(),
    }
