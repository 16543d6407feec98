"""``proto/vectors/sdk/interp.json``: the jitter buffer (``PoseBuffer``,
``docs/game-engines.md`` and the SDKs' interp modules).

Each case is a config and a list of steps: a push (a pose, a keyframe flag, whether
the buffer keeps it) or a query (a server time and the pose expected then, or
``null``). The expected poses are worked out here from the rules with other math than
the SDKs use: slerp as ``q0 * exp(u * log(q0^-1 q1))`` on the server's axis-angle
helpers (the SDKs use the sine formula), extrapolation as the same exponential with
``u > 1``. These cases pin the rules at a fixed delay (``adaptive: false``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from _sdk_common import F64, J, unit
from _sdk_delay import DELAY_DEFAULTS

from posecast.geometry.rotations import aa2quat, quat2aa, quat_conj, quat_mul

DT = 1.0 / 60.0
T0 = 100.0  # server time of the first pose, seconds
DEFAULTS = {**DELAY_DEFAULTS, "adaptive": False}  # the rules, at a fixed delay
TOLERANCE = {"position_m": 1e-9, "rotation": 1e-9}


# --- the reference, written from the rules ----------------------------------------------------


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


# --- the cases: a seeded motion, pushes and queries -------------------------------------------


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


def interp() -> dict[str, Any]:
    return {
        "description": "PoseBuffer behaviour (docs/game-engines.md, Interpolation): run the "
        "steps in order on one buffer with the case's config; compare positions within "
        "tolerance.position_m and rotations per joint up to sign within tolerance.rotation",
        "tolerance": TOLERANCE,
        "cases": interp_cases(),
    }
