"""Write the SDK behaviour tables ``proto/vectors/sdk/interp.json``, ``delay.json``,
``conventions.json`` and ``clock.json``.

    .venv/bin/python proto/vectors/generate_sdk.py           # rewrite the files
    .venv/bin/python proto/vectors/generate_sdk.py --check   # exit 1 if they are stale

These are not wire vectors (the codec readers glob ``proto/vectors/*.json``, so they
live one folder down): they pin what both SDKs do with decoded poses.

``interp.json``: the jitter buffer (``PoseBuffer``, ``docs/game-engines.md`` and the SDKs'
interp modules). Each case is a config and a list of steps: a push (a pose, a keyframe
flag, whether the buffer keeps it) or a query (a server time and the pose expected
then, or ``null``). The expected poses are worked out here from the rules with other
math than the SDKs use: slerp as ``q0 * exp(u * log(q0^-1 q1))`` on the server's
axis-angle helpers (the SDKs use the sine formula), extrapolation as the same
exponential with ``u > 1``. These cases pin the rules at a fixed delay
(``adaptive: false``).

``delay.json``: the adaptive render delay on simulated arrival sequences
(``_sdk_delay.py``).

``conventions.json``: each engine's frame as up/forward/right axes and a unit, poses
converted by the rotation-matrix route ``R' = M R M^T`` (the SDKs flip quaternion
components), the WebXR view turn, and the joint -> bone-name table, which is defined
here and copied by both SDKs.

``clock.json``: ``ClockSync``'s display clock (``display_time``; ``docs/game-engines.md``,
"Interpolation"). Each case is a config and a list of steps: an exchange added (its
four times and the estimate after it), a display query (a client time and the display
time expected then, ``null`` before the first pong: Python and C# return the client
time there, TypeScript throws), or a reset. The expected values are the Python SDK's
own (``posecast_client.clock``): the rules are short, and this pins the other SDKs to
it; each query also names the rule it exercises, and every rule is checked to occur.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from posecast_client.clock import ClockSync

from posecast.geometry.rotations import aa2quat, mat2quat, quat2aa, quat2mat, quat_conj, quat_mul
from posecast.skeleton import Joint

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the helper modules beside this script
from _sdk_delay import DELAY_DEFAULTS, render_delay_table  # noqa: E402

OUT = HERE / "sdk"
F64 = NDArray[np.float64]
J = len(Joint)
DT = 1.0 / 60.0
T0 = 100.0  # server time of the first pose, seconds
DEFAULTS = {**DELAY_DEFAULTS, "adaptive": False}  # the rules, at a fixed delay
TOLERANCE = {"position_m": 1e-9, "rotation": 1e-9}


# --- interpolation: the reference, written from the rules -----------------------------------


def unit(q: F64) -> F64:
    out: F64 = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out


def slerp_ref(q0: F64, q1: F64, u: float) -> F64:
    """``q0 * exp(u * log(q0^-1 * q1))``; ``quat2aa`` takes the short way (w >= 0)."""
    a, b = unit(q0), unit(q1)
    rel = quat2aa(quat_mul(quat_conj(a), b))  # (J, 3) axis * angle, angle <= pi
    return unit(quat_mul(a, aa2quat(u * rel)))


class Reference:
    """The buffer's rules, step by step (kept apart from both SDKs' code)."""

    def __init__(self, cfg: dict[str, Any]) -> None:
        self.cfg = cfg
        self.poses: list[dict[str, Any]] = []
        self.last: dict[str, Any] | None = None  # what the last query showed

    def shown(self, time: float) -> dict[str, Any] | None:
        """Rule 5: the sample, plus the last frame's correction fading out."""
        tau = time - self.cfg["delay_s"]
        raw, last = self.query(time), self.last
        self.last = raw
        if raw is None or last is None or not self.blends(last["t"], tau):
            return raw
        before = self.query(last["t"] + self.cfg["delay_s"])
        assert before is not None
        k = np.exp(-(tau - last["t"]) / self.cfg["correction_s"])
        off = np.array(last["positions"]) - np.array(before["positions"])
        out = {**raw, "positions": (np.array(raw["positions"]) + k * off).tolist()}
        if raw["rotations"] and last["rotations"] and before["rotations"]:
            delta = quat_mul(np.array(last["rotations"]), quat_conj(np.array(before["rotations"])))
            faded = aa2quat(k * quat2aa(delta))  # exp(k log delta)
            out["rotations"] = quat_mul(faded, np.array(raw["rotations"])).tolist()
        self.last = out
        return out

    def blends(self, last_tau: float, tau: float) -> bool:
        if self.cfg["correction_s"] == 0 or not 0 < tau - last_tau <= self.cfg["gap_s"]:
            return False
        pairs = zip(self.poses, self.poses[1:], strict=False)
        return not any(last_tau < b["t"] <= tau and self.snaps(a, b) for a, b in pairs)

    def push(self, pose: dict[str, Any]) -> bool:
        if any(p["t"] == pose["t"] for p in self.poses):
            return False
        if len(self.poses) >= self.cfg["capacity"] and pose["t"] < min(p["t"] for p in self.poses):
            return False
        self.poses = sorted([*self.poses, pose], key=lambda p: p["t"])[-self.cfg["capacity"] :]
        return True

    def snaps(self, a: dict[str, Any], b: dict[str, Any]) -> bool:
        root_jump = np.linalg.norm(np.subtract(b["positions"][0], a["positions"][0]))
        seq_newer = 0 < (b["seq"] - a["seq"]) % 2**32 < 2**31
        return bool(
            b["t"] - a["t"] > self.cfg["gap_s"]
            or (b["keyframe"] and not seq_newer)
            or root_jump > self.cfg["teleport_m"]
        )

    def query(self, time: float) -> dict[str, Any] | None:
        if not self.poses:
            return None
        tau = time - self.cfg["delay_s"]
        before = [p for p in self.poses if p["t"] <= tau]
        if not before:
            return self.out(self.poses[0], tau, "hold")
        a = before[-1]
        after = [p for p in self.poses if p["t"] > tau]
        if after and not self.snaps(a, after[0]):
            b = after[0]
            u = (tau - a["t"]) / (b["t"] - a["t"])
            pos = (1.0 - u) * np.array(a["positions"]) + u * np.array(b["positions"])
            rot = self.rot_between(a, b, u)
            return self.out(a, tau, "interpolate", pos, rot)
        prev = before[-2] if len(before) >= 2 else None
        if prev is None or self.snaps(prev, a) or self.cfg["max_extrapolate_s"] == 0:
            return self.out(a, tau, "hold")
        ahead = tau - a["t"]
        bound = self.cfg["max_extrapolate_s"]
        u = 1.0 + min(ahead, bound) / (a["t"] - prev["t"])
        pos = (1.0 - u) * np.array(prev["positions"]) + u * np.array(a["positions"])
        mode = "extrapolate" if ahead <= bound else "hold"
        return self.out(a, tau, mode, pos, self.rot_between(prev, a, u))

    @staticmethod
    def rot_between(a: dict[str, Any], b: dict[str, Any], u: float) -> F64 | None:
        if a["rotations"] is None or b["rotations"] is None:
            return None
        return slerp_ref(np.array(a["rotations"]), np.array(b["rotations"]), u)

    @staticmethod
    def out(
        a: dict[str, Any], tau: float, mode: str, pos: F64 | None = None, rot: F64 | None = None
    ) -> dict[str, Any]:
        if pos is None:  # hold a as it is
            pos = np.array(a["positions"])
            rot = None if a["rotations"] is None else unit(np.array(a["rotations"]))
        return {
            "t": tau,
            "seq": a["seq"],
            "mode": mode,
            "positions": pos.tolist(),
            "rotations": None if rot is None else rot.tolist(),
        }


class Motion:
    """A seeded body: every joint turns about two axes and moves along a curve, so
    neither positions nor rotations are linear in time (extrapolation and
    interpolation then give different answers)."""

    def __init__(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.axes = unit(rng.normal(size=(2, J, 3)))
        self.rates = rng.uniform(-6.0, 6.0, size=(J, 1))  # rad/s; some joints turn fast
        self.phase = rng.uniform(-np.pi, np.pi, size=(2, J, 1))
        self.base = rng.uniform(-1.0, 1.0, size=(J, 3)) + np.array([0.0, 1.0, 0.0])
        self.vel = rng.uniform(-1.5, 1.5, size=(J, 3))  # m/s
        self.amp = rng.uniform(0.0, 0.2, size=(J, 3))  # m, at 1.5 Hz

    def pose(self, seq: int, t: float, *, shift: float = 0.0, flip: bool = False) -> dict[str, Any]:
        c = t - T0  # clip time: the clip starts at T0 on the server clock
        wave = self.amp * np.sin(2 * np.pi * 1.5 * c + self.phase[0])
        pos = self.base + self.vel * c + wave + [shift, 0.0, 0.0]
        turn = aa2quat(self.axes[0] * (self.phase[0] + self.rates * c))
        sway = aa2quat(self.axes[1] * 0.8 * np.sin(4.0 * c + self.phase[1]))
        rot = quat_mul(turn, sway)
        if flip:  # the same rotations, every other joint on the other hemisphere
            rot[::2] = -rot[::2]
        return as_push(seq, t, pos, rot)


def as_push(seq: int, t: float, pos: F64, rot: F64) -> dict[str, Any]:
    return {
        "seq": seq,
        "t": round(t, 9),
        "keyframe": False,
        "positions": np.round(pos, 6).tolist(),
        "rotations": np.round(rot, 6).tolist(),
    }


def rounded(out: dict[str, Any] | None) -> dict[str, Any] | None:
    """12 decimals: far inside the tolerance, and a shorter file."""
    if out is None:
        return None
    rot = out["rotations"]
    return {
        **out,
        "positions": np.round(out["positions"], 12).tolist(),
        "rotations": None if rot is None else np.round(unit(np.array(rot)), 12).tolist(),
    }


def case(
    name: str, description: str, steps: list[Any], *, corrects: bool = False, **cfg: Any
) -> dict[str, Any]:
    """Run ``steps`` on the reference. ``corrects``: rule 5 must change some frame
    (and no frame elsewhere), so each case tests what it says."""
    config = {**DEFAULTS, **cfg}
    ref = Reference(config)
    out = []
    correction = 0.0
    for step in steps:
        if "query" in step:
            raw = ref.query(step["query"])
            shown = ref.shown(step["query"])
            if raw is not None and shown is not None:
                diff = np.subtract(raw["positions"], shown["positions"])
                correction = max(correction, float(np.abs(diff).max()))
            out.append({"query": step["query"], "expect": rounded(shown)})
        else:
            pose = step["push"]
            out.append({"push": pose, "accepted": ref.push(pose)})
    assert (correction > 1e-3) if corrects else (correction == 0.0), (name, correction)
    return {"name": name, "description": description, "config": config, "steps": out}


def push(pose: dict[str, Any], *, keyframe: bool = False, rotations: bool = True) -> dict[str, Any]:
    p = {**pose, "keyframe": keyframe}
    if not rotations:
        p["rotations"] = None
    return {"push": p}


def q(tau: float, delay: float = 0.1) -> dict[str, Any]:
    return {"query": round(tau + delay, 9)}


def interp_cases() -> list[dict[str, Any]]:
    m = Motion(14)
    ts = [T0 + k * DT for k in range(8)]
    p = [m.pose(k + 1, ts[k]) for k in range(8)]
    rng = np.random.default_rng(16)
    big = [
        as_push(k + 1, ts[k], rng.uniform(-0.3, 0.3, size=(J, 3)), unit(rng.normal(size=(J, 4))))
        for k in range(2)
    ]
    return [
        case(
            "interpolate_between_neighbours",
            "three poses at 60 Hz; queries on a pose, a quarter, half and 0.9 of the way",
            [
                push(p[0]),
                push(p[1]),
                push(p[2]),
                q(ts[0]),
                q(ts[0] + 0.25 * DT),
                q(ts[1] + 0.5 * DT),
                q(ts[1] + 0.9 * DT),
                q(ts[2]),
            ],
        ),
        case(
            "empty_then_before_first",
            "no pose yet gives null; before the first pose it is held",
            [q(ts[0]), push(p[1]), push(p[2]), q(ts[0]), q(ts[1] - 0.5 * DT)],
        ),
        case(
            "hemisphere",
            "the second pose stores every other joint's quaternion negated: the same output",
            [
                push(p[0]),
                push(m.pose(2, ts[1], flip=True)),
                q(ts[0] + 0.5 * DT),
                q(ts[0] + 0.75 * DT),
            ],
        ),
        case(
            "out_of_order_and_duplicate",
            "pushed 3, 1, 2, then 2 again (dropped): the same samples as in order",
            [
                push(p[2]),
                push(p[0]),
                push(p[1]),
                push(p[1]),
                q(ts[0] + 0.5 * DT),
                q(ts[1] + 0.5 * DT),
            ],
        ),
        case(
            "lost_pose_is_bridged",
            "seq 3 never arrives: 2 -> 4 interpolates over 33 ms",
            [
                push(p[0]),
                push(p[1]),
                push(p[3]),
                push(p[4]),
                q(ts[1] + 0.5 * DT),
                q(ts[2]),
                q(ts[2] + 0.7 * DT),
            ],
        ),
        case(
            "extrapolate_then_hold",
            "past the newest pose: carried on for at most 0.1 s, then held there",
            [push(p[0]), push(p[1]), q(ts[1] + 0.02), q(ts[1] + 0.09), q(ts[1] + 0.3)],
        ),
        case(
            "late_pose_replaces_extrapolation",
            "extrapolated while pose 3 is late; once it arrives the same time interpolates",
            [push(p[0]), push(p[1]), q(ts[1] + 0.5 * DT), push(p[2]), q(ts[1] + 0.5 * DT)],
        ),
        case(
            "teleport_snaps",
            "pose 3's pelvis is 3 m away: no blend; pose 2 carried on until 3, then pose 3 "
            "exactly, then 3 -> 4 interpolates",
            [
                push(p[0]),
                push(p[1]),
                push(m.pose(3, ts[2], shift=3.0)),
                push(m.pose(4, ts[3], shift=3.0)),
                q(ts[1] + 0.5 * DT),
                q(ts[2]),
                q(ts[2] + 0.5 * DT),
            ],
        ),
        case(
            "gap_snaps",
            "0.5 s without poses (beyond gap_s): carried on 0.1 s and held, then a snap",
            [
                push(p[0]),
                push(p[1]),
                push(m.pose(40, ts[1] + 0.5)),
                push(m.pose(41, ts[1] + 0.5 + DT)),
                q(ts[1] + 0.05),
                q(ts[1] + 0.3),
                q(ts[1] + 0.5),
                q(ts[1] + 0.5 + 0.5 * DT),
            ],
        ),
        case(
            "keyframe_with_older_seq_snaps",
            "a keyframe with seq 0 after seq 2 (no time gap: a new sequence, a rejoin): "
            "a snap; a keyframe after a forward seq gap (seq 4 after 0, as at a 15 Hz "
            "pose rate) blends",
            [
                push(p[0]),
                push(p[1]),
                push(m.pose(0, ts[2]), keyframe=True),
                push(m.pose(4, ts[3]), keyframe=True),
                q(ts[1] + 0.5 * DT),
                q(ts[2] + 0.5 * DT),
            ],
        ),
        case(
            "correction_fades",
            "poses 3-6 are late: frames at 90 Hz extrapolate from 2; once they arrive "
            "the difference fades out over correction_s instead of showing as one step",
            [
                push(p[0]),
                push(p[1]),
                *(q(ts[1] + k / 90) for k in range(3)),
                push(p[2]),
                push(p[3]),
                push(p[4]),
                push(p[5]),
                *(q(ts[1] + k / 90) for k in range(3, 8)),
            ],
            corrects=True,
        ),
        case(
            "correction_off",
            "correction_s 0: the same frames show the new answer at once",
            [
                push(p[0]),
                push(p[1]),
                *(q(ts[1] + k / 90) for k in range(3)),
                push(p[2]),
                push(p[3]),
                push(p[4]),
                push(p[5]),
                *(q(ts[1] + k / 90) for k in range(3, 5)),
            ],
            correction_s=0.0,
        ),
        case(
            "correction_stops_at_a_snap",
            "a correction is pending when a teleported pose begins a segment: that "
            "frame shows the new segment exactly",
            [
                push(p[0]),
                push(p[1]),
                q(ts[1] + 1 / 90),
                q(ts[1] + 2 / 90),
                push(p[2]),
                push(m.pose(4, ts[3], shift=3.0)),
                push(m.pose(5, ts[4], shift=3.0)),
                q(ts[3] + 0.1 * DT),
                q(ts[3] + 0.25 * DT),
            ],
        ),
        case(
            "capacity",
            "capacity 4: six poses keep the last four; an older pose is refused",
            [
                *(push(x) for x in p[:6]),
                push(m.pose(0, ts[0] - DT)),
                q(ts[0]),
                q(ts[2]),
                q(ts[3] + 0.5 * DT),
            ],
            capacity=4,
        ),
        case(
            "large_angles",
            "two unrelated random poses 1/60 s apart (turns up to 180 degrees, either "
            "hemisphere): slerp, not a normalised lerp",
            [push(big[0]), push(big[1]), q(ts[0] + 0.3 * DT), q(ts[0] + 0.8 * DT)],
        ),
        case(
            "positions_only",
            "poses without rotations (v1 positions-only) give samples without rotations",
            [
                push(p[0], rotations=False),
                push(p[1], rotations=False),
                q(ts[0] + 0.5 * DT),
                q(ts[1] + 0.05),
            ],
        ),
        case(
            "short_delay_and_bound",
            "delay 0.05 s, extrapolation at most 0.02 s",
            [
                push(p[0]),
                push(p[1]),
                q(ts[0] + 0.5 * DT, 0.05),
                q(ts[1] + 0.01, 0.05),
                q(ts[1] + 0.08, 0.05),
            ],
            delay_s=0.05,
            max_extrapolate_s=0.02,
        ),
    ]


# --- the display clock ------------------------------------------------------------------------

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


# --- engine conventions ---------------------------------------------------------------------

# posecast's character axes: forward +Z, up +Y, right -X (its left is +X).
FORWARD, UP, RIGHT = np.array([0.0, 0, 1]), np.array([0.0, 1, 0]), np.array([-1.0, 0, 0])
# Where each engine puts them, in its own coordinates, and its length unit per metre.
ENGINES: dict[str, dict[str, Any]] = {
    "unity": {"forward": [0, 0, 1], "up": [0, 1, 0], "right": [1, 0, 0], "scale": 1.0,
              "right_handed": False, "note": "left-handed, +Y up, +Z forward, metres"},
    "unreal": {"forward": [1, 0, 0], "up": [0, 0, 1], "right": [0, 1, 0], "scale": 100.0,
               "right_handed": False, "note": "left-handed, +Z up, +X forward, centimetres"},
    "three": {"forward": [0, 0, 1], "up": [0, 1, 0], "right": [-1, 0, 0], "scale": 1.0,
              "right_handed": True, "note": "three.js / WebXR / glTF: posecast's own frame"},
}  # fmt: skip

# joint: Unity HumanBodyBones, VRM humanoid, UE5 Manny/Quinn, UE4 SK_Mannequin.
BONES = {
    "PELVIS": ("Hips", "hips", "pelvis", "pelvis"),
    "SPINE": ("Spine", "spine", "spine_01", "spine_01"),
    "CHEST": ("Chest", "chest", "spine_05", "spine_03"),
    "NECK": ("Neck", "neck", "neck_01", "neck_01"),
    "HEAD": ("Head", "head", "head", "head"),
    "LEFT_UPPER_ARM": ("LeftUpperArm", "leftUpperArm", "upperarm_l", "upperarm_l"),
    "LEFT_FOREARM": ("LeftLowerArm", "leftLowerArm", "lowerarm_l", "lowerarm_l"),
    "LEFT_HAND": ("LeftHand", "leftHand", "hand_l", "hand_l"),
    "RIGHT_UPPER_ARM": ("RightUpperArm", "rightUpperArm", "upperarm_r", "upperarm_r"),
    "RIGHT_FOREARM": ("RightLowerArm", "rightLowerArm", "lowerarm_r", "lowerarm_r"),
    "RIGHT_HAND": ("RightHand", "rightHand", "hand_r", "hand_r"),
    "LEFT_THIGH": ("LeftUpperLeg", "leftUpperLeg", "thigh_l", "thigh_l"),
    "LEFT_SHIN": ("LeftLowerLeg", "leftLowerLeg", "calf_l", "calf_l"),
    "LEFT_FOOT": ("LeftFoot", "leftFoot", "foot_l", "foot_l"),
    "LEFT_TOE": ("LeftToes", "leftToes", "ball_l", "ball_l"),
    "RIGHT_THIGH": ("RightUpperLeg", "rightUpperLeg", "thigh_r", "thigh_r"),
    "RIGHT_SHIN": ("RightLowerLeg", "rightLowerLeg", "calf_r", "calf_r"),
    "RIGHT_FOOT": ("RightFoot", "rightFoot", "foot_r", "foot_r"),
    "RIGHT_TOE": ("RightToes", "rightToes", "ball_r", "ball_r"),
}
RIGS = ("unity", "vrm", "unreal", "unreal_ue4")


def basis(engine: str) -> F64:
    """``M`` with ``p_engine = M @ p_posecast`` (before the unit): it sends posecast's
    forward, up and right onto the engine's."""
    e = ENGINES[engine]
    src = np.stack([FORWARD, UP, RIGHT], axis=1)  # columns: posecast axes
    dst = np.array([e["forward"], e["up"], e["right"]], dtype=np.float64).T
    m: F64 = dst @ np.linalg.inv(src)
    return m


def convert(engine: str, pos: F64, rot: F64) -> tuple[F64, F64]:
    m = basis(engine)
    assert np.isclose(np.linalg.det(m), 1.0 if ENGINES[engine]["right_handed"] else -1.0)
    new_pos = ENGINES[engine]["scale"] * pos @ m.T
    new_rot = mat2quat(m @ quat2mat(rot) @ m.T)  # (..., 3, 3): the same turn, seen there
    return new_pos, new_rot


def conventions() -> dict[str, Any]:
    rng = np.random.default_rng(15)
    yaw_left = aa2quat([0.0, np.pi / 2, 0.0])  # the character turns to its left
    named = {
        "forward_1m": ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]),
        "left_1m": ([1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
        "up_1m": ([0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
        "turn_left_90": ([0.0, 0.0, 0.0], yaw_left.tolist()),
        "raise_left_arm_45": ([0.17, 1.45, 0.0], aa2quat([0.0, 0.0, np.pi / 4]).tolist()),
    }
    cases = []
    for engine in ENGINES:
        # What a turn to the left means there: engine forward ends on engine -right.
        _, r = convert(engine, np.zeros(3), yaw_left)
        fwd_after = quat2mat(r) @ np.array(ENGINES[engine]["forward"], dtype=np.float64)
        assert np.allclose(fwd_after, -np.array(ENGINES[engine]["right"])), engine
        for name, (p, rot) in named.items():
            pos2, rot2 = convert(engine, np.array([p]), np.array([rot]))
            cases.append({
                "name": f"{engine}_{name}", "engine": engine,
                "positions": [p], "rotations": [rot],
                "expect_positions": pos2.tolist(), "expect_rotations": rot2.tolist(),
            })  # fmt: skip
        pos = np.round(rng.uniform(-2, 2, size=(J, 3)), 6)
        rot = unit(rng.normal(size=(J, 4)))
        pos2, rot2 = convert(engine, pos, rot)
        cases.append({
            "name": f"{engine}_random_pose", "engine": engine,
            "positions": pos.tolist(), "rotations": rot.tolist(),
            "expect_positions": pos2.tolist(), "expect_rotations": rot2.tolist(),
        })  # fmt: skip
    heads = unit(rng.normal(size=(4, 4)))
    views = [[0.0, 0.0, 0.0, 1.0], *heads.tolist()]
    xr = [quat_mul(np.array(v), [0.0, 1.0, 0.0, 0.0]).tolist() for v in views]
    # A camera at the head: its -Z (where it looks) is the head's +Z (where it faces).
    for v, c in zip(views, xr, strict=True):
        assert np.allclose(quat2mat(c) @ [0, 0, -1.0], quat2mat(v) @ [0, 0, 1.0])
    return {
        "description": "posecast poses in engine frames (docs/game-engines.md); compare "
        "positions within tolerance.position_m (engine units) and rotations up to sign",
        "tolerance": {"position": 1e-9, "rotation": 1e-9},
        "engines": {k: {**v, "basis": basis(k).round(12).tolist()} for k, v in ENGINES.items()},
        "cases": cases,
        "head2xrview": [{"head": v, "view": c} for v, c in zip(views, xr, strict=True)],
        "bones": [
            {"joint": j, **dict(zip(RIGS, names, strict=True))} for j, names in BONES.items()
        ],
    }


def interp() -> dict[str, Any]:
    return {
        "description": "PoseBuffer behaviour (docs/game-engines.md, Interpolation): run the "
        "steps in order on one buffer with the case's config; compare positions within "
        "tolerance.position_m and rotations per joint up to sign within tolerance.rotation",
        "tolerance": TOLERANCE,
        "cases": interp_cases(),
    }


def render(obj: Any) -> str:
    """JSON with one line per object field; a list of numbers (or of number lists, a
    pose's array) stays on one line."""
    return _render(obj, 0) + "\n"


def _flat(v: Any) -> bool:
    return isinstance(v, list) and all(
        isinstance(x, int | float) or (isinstance(x, list) and _flat(x)) for x in v
    )


def _render(v: Any, depth: int) -> str:
    pad, inner = " " * depth, " " * (depth + 1)
    if isinstance(v, dict) and v:
        items = [f"{inner}{json.dumps(k)}: {_render(x, depth + 1)}" for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(v, list) and v and not _flat(v):
        return "[\n" + ",\n".join(inner + _render(x, depth + 1) for x in v) + "\n" + pad + "]"
    return json.dumps(v, separators=(",", ":")) if isinstance(v, list) else json.dumps(v)


def main(argv: list[str]) -> int:
    outputs = {
        OUT / "interp.json": render(interp()),
        OUT / "delay.json": render_delay_table(),
        OUT / "conventions.json": render(conventions()),
        OUT / "clock.json": render(clock()),
    }
    stale = []
    for path, text in outputs.items():
        if "--check" in argv:
            if not path.exists() or path.read_text() != text:
                stale.append(path.name)
        else:
            path.parent.mkdir(exist_ok=True)
            path.write_text(text)
    if stale:
        print("stale SDK vector files:", ", ".join(stale), file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
