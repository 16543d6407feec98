"""Vectors of the motion messages: calibrate, frame, pose, selector."""

from __future__ import annotations

from typing import Any

import numpy as np
from _writer import invalid, pack, valid

from posecast.online.protocol import codec
from posecast.online.protocol import messages as m

ID_Q = [0.0, 0.0, 0.0, 1.0]
HALF_Q = [0.5, 0.5, 0.5, 0.5]
# Four trackers with values exact in float32 and unit quaternions whose norm is
# exactly 1.0, so every variant decodes to the very same float64 message.
TRACKERS = [
    [0.25, 1.625, 0.5, *ID_Q],
    [0.5, 1.125, 0.75, *HALF_Q],
    [-0.375, 1.0, 0.625, 0.5, -0.5, 0.5, 0.5],
    [0.125, 0.96875, 0.25, 0.0, 1.0, 0.0, 0.0],
]


def _frame(
    seq: int = 7, t: float = 12.5, rows: list[list[float]] = TRACKERS, valid: int = 15
) -> m.Frame:
    a = np.array(rows, dtype=np.float64)
    return m.Frame(seq, t, a[:, :3].copy(), a[:, 3:].copy(), valid)


# Six sites (a set such as head, hands, waist, both feet; the last two could as well be
# IMUs' accelerations), values exact in float32 and unit quaternions.
SITES = [
    *TRACKERS,
    [0.125, 0.0625, 0.375, *ID_Q],
    [-0.125, 9.75, -0.5, *HALF_Q],
]


def _sites(
    seq: int = 9, t: float = 3.25, valid: int = 63, rows: list[list[float]] = SITES
) -> m.Frame:
    a = np.array(rows, dtype=np.float64)
    return m.Frame(seq, t, a[:, :3].copy(), a[:, 3:].copy(), valid, sites=True)


def _sites_wire(**changes: Any) -> dict[str, Any]:
    return {**codec.to_wire(_sites()), **changes}


def _frame_wire(**changes: Any) -> dict[str, Any]:
    return {**codec.to_wire(_frame()), **changes}


def _tracker(i: int, row: list[Any]) -> dict[str, Any]:
    rows = [list(r) for r in TRACKERS]
    rows[i] = row
    return _frame_wire(trackers=rows)


def _unit(q: list[float]) -> list[float]:
    """Normalise until the spec's left-to-right norm is exactly 1.0 (so it is stable)."""
    for _ in range(8):
        n = float(np.sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3]))
        if n == 1.0:
            return q
        q = [v / n for v in q]
    raise AssertionError(q)


def _realistic_rows() -> list[list[float]]:
    rng = np.random.default_rng(1)
    pos = [[0.031, 1.712, 0.204], [0.287, 1.093, 0.418], [-0.305, 1.118, 0.377], [0.02, 1.04, 0.18]]
    return [p + _unit(rng.normal(size=4).tolist()) for p in pos]


def calibrate_cases() -> list[dict[str, Any]]:
    tpose = _frame()
    return [
        valid("calibrate_height", m.Calibrate(height_m=1.75), "by standing height"),
        valid("calibrate_tpose", m.Calibrate(pos=tpose.pos, quat=tpose.quat), "by a T-pose frame"),
        valid(
            "calibrate_tpose_sites",
            m.Calibrate(pos=_sites().pos, quat=_sites().quat, sites=True),
            "a tracker set's T-pose: every site, in the set's order",
        ),
        invalid(
            "calibrate_sites_and_trackers",
            {"type": "calibrate", "tpose": True, "trackers": TRACKERS, "sites": SITES},
            "BAD_FIELD",
            "both row fields",
            "sites",
        ),
        invalid("calibrate_empty", {"type": "calibrate"}, "BAD_FIELD", "neither way", "height_m"),
        invalid(
            "calibrate_both",
            {"type": "calibrate", "height_m": 1.75, "tpose": True, "trackers": TRACKERS},
            "BAD_FIELD",
            "both ways at once",
            "tpose",
        ),
        invalid(
            "calibrate_tpose_false",
            {"type": "calibrate", "tpose": False},
            "BAD_FIELD",
            "tpose must be true",
            "tpose",
        ),
        invalid(
            "calibrate_tpose_int",
            {"type": "calibrate", "tpose": 1, "trackers": TRACKERS},
            "BAD_FIELD",
            "1, not true",
            "tpose",
        ),
        invalid(
            "calibrate_tpose_no_trackers",
            {"type": "calibrate", "tpose": True},
            "BAD_FIELD",
            "no frame",
            "trackers",
        ),
        invalid(
            "calibrate_height_short",
            {"type": "calibrate", "height_m": 0.5},
            "OUT_OF_RANGE",
            "0.5 m",
            "height_m",
        ),
        invalid(
            "calibrate_height_tall",
            {"type": "calibrate", "height_m": 3},
            "OUT_OF_RANGE",
            "3 m",
            "height_m",
        ),
        invalid(
            "calibrate_height_nan",
            {"type": "calibrate", "height_m": float("nan")},
            "OUT_OF_RANGE",
            "NaN",
            "height_m",
        ),
        invalid(
            "calibrate_tpose_not_normalised",
            {
                "type": "calibrate",
                "tpose": True,
                "trackers": [TRACKERS[0], TRACKERS[1], TRACKERS[2], [0.0] * 7],
            },
            "NOT_NORMALISED",
            "a zero quaternion",
            "trackers[3]",
        ),
    ]


def frame_cases() -> list[dict[str, Any]]:
    f = _frame()
    w = 1.0 + 2.0**-10  # | |q| - 1 | = 9.8e-4: within tolerance, renormalises to exactly 1
    nudged = [r[:3] + [v * w for v in r[3:]] for r in TRACKERS]
    lost = [list(r) for r in TRACKERS]
    lost[3] = [0.0, 0.0, 0.0, *ID_Q]
    nan_lost = [*lost[:3], [float("nan")] * 7]
    edge = [[1000.0, -1000.0, 1000.0, *ID_Q], *TRACKERS[1:]]
    big = [list(r) for r in TRACKERS]
    big[3] = [1000.5, 0.0, 0.0, *ID_Q]
    return [
        valid("frame", f, "four tracked points"),
        valid(
            "frame_renormalised",
            f,
            "quaternions off unit length by 9.8e-4 are accepted and renormalised",
            (pack(_frame_wire(trackers=nudged)),),
        ),
        valid(
            "frame_realistic", _frame(123456, 1712.0345, _realistic_rows()), "real-looking numbers"
        ),
        valid("frame_seq_zero", _frame(seq=0, t=0.0), "the smallest seq and time"),
        valid("frame_seq_max", _frame(seq=2**32 - 1), "the largest seq (the next one is 0)"),
        valid("frame_world_edge", _frame(rows=edge), "positions at exactly +-1000 m"),
        valid(
            "frame_waist_lost",
            _frame(rows=lost, valid=0b0111),
            "waist untracked: its values are ignored (NaN allowed), read as origin + identity",
            (pack(_frame_wire(trackers=nan_lost, valid=7)),),
        ),
        valid("frame_sites", _sites(), "a tracker set's six rows, all tracked"),
        valid(
            "frame_sites_partial",
            _sites(valid=0b101111, rows=[*SITES[:4], [0.0, 0.0, 0.0, *ID_Q], SITES[5]]),
            "a tracker set's frame with row 4 lost: read as origin + identity",
        ),
        invalid(
            "frame_sites_valid_beyond",
            _sites_wire(sites=SITES[:3], valid=8),
            "OUT_OF_RANGE",
            "valid names a fourth row of three",
            "valid",
        ),
        invalid(
            "frame_sites_and_trackers",
            _sites_wire(trackers=TRACKERS),
            "BAD_FIELD",
            "both row fields",
            "sites",
        ),
        invalid("frame_sites_empty", _sites_wire(sites=[]), "BAD_FIELD", "no rows", "sites"),
        invalid(
            "frame_sites_eleven",
            _sites_wire(sites=[*SITES, *SITES[:5]]),
            "BAD_FIELD",
            "eleven rows (at most 10)",
            "sites",
        ),
        invalid(
            "frame_sites_quat_zero",
            _sites_wire(sites=[*SITES[:5], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]]),
            "NOT_NORMALISED",
            "a zero quaternion in row 5",
            "sites[5]",
        ),
        invalid(
            "frame_missing_seq",
            {k: v for k, v in _frame_wire().items() if k != "seq"},
            "BAD_FIELD",
            "no seq",
            "seq",
        ),
        invalid("frame_seq_float", _frame_wire(seq=7.0), "BAD_FIELD", "seq 7.0", "seq"),
        invalid("frame_seq_string", _frame_wire(seq="7"), "BAD_FIELD", "seq '7'", "seq"),
        invalid("frame_seq_bool", _frame_wire(seq=True), "BAD_FIELD", "seq true", "seq"),
        invalid("frame_seq_negative", _frame_wire(seq=-1), "OUT_OF_RANGE", "seq -1", "seq"),
        invalid("frame_seq_too_big", _frame_wire(seq=2**32), "OUT_OF_RANGE", "seq 2**32", "seq"),
        invalid("frame_t_negative", _frame_wire(t=-0.5), "OUT_OF_RANGE", "t -0.5", "t"),
        invalid("frame_t_inf", _frame_wire(t=float("inf")), "OUT_OF_RANGE", "t +Inf", "t"),
        invalid("frame_t_string", _frame_wire(t="now"), "BAD_FIELD", "t 'now'", "t"),
        invalid(
            "frame_missing_trackers",
            {k: v for k, v in _frame_wire().items() if k != "trackers"},
            "BAD_FIELD",
            "no trackers",
            "trackers",
        ),
        invalid(
            "frame_three_trackers",
            _frame_wire(trackers=TRACKERS[:3]),
            "BAD_FIELD",
            "3 trackers",
            "trackers",
        ),
        invalid(
            "frame_five_trackers",
            _frame_wire(trackers=[*TRACKERS, TRACKERS[0]]),
            "BAD_FIELD",
            "5 trackers",
            "trackers",
        ),
        invalid(
            "frame_trackers_bin",
            _frame_wire(trackers=b"\x00" * 112),
            "BAD_FIELD",
            "a bin",
            "trackers",
        ),
        invalid(
            "frame_tracker_short",
            _tracker(1, TRACKERS[1][:6]),
            "BAD_FIELD",
            "6 numbers",
            "trackers[1]",
        ),
        invalid(
            "frame_tracker_nested",
            _tracker(0, [TRACKERS[0][:3], TRACKERS[0][3:]]),
            "BAD_FIELD",
            "[[p], [q]] instead of [p..., q...]",
            "trackers[0]",
        ),
        invalid(
            "frame_tracker_string",
            _tracker(2, [*TRACKERS[2][:6], "0.5"]),
            "BAD_FIELD",
            "a str",
            "trackers[2]",
        ),
        invalid(
            "frame_tracker_bool",
            _tracker(2, [True, *TRACKERS[2][1:]]),
            "BAD_FIELD",
            "a bool",
            "trackers[2]",
        ),
        invalid(
            "frame_tracker_nil",
            _tracker(2, [None, *TRACKERS[2][1:]]),
            "BAD_FIELD",
            "a nil",
            "trackers[2]",
        ),
        invalid(
            "frame_position_nan",
            _tracker(0, [float("nan"), *TRACKERS[0][1:]]),
            "OUT_OF_RANGE",
            "NaN",
            "trackers[0]",
        ),
        invalid(
            "frame_position_inf",
            _tracker(1, [0.0, float("-inf"), *TRACKERS[1][2:]]),
            "OUT_OF_RANGE",
            "-Inf",
            "trackers[1]",
        ),
        invalid(
            "frame_position_absurd",
            _frame_wire(trackers=big),
            "OUT_OF_RANGE",
            "1000.5 m",
            "trackers[3]",
        ),
        invalid(
            "frame_position_huge_int",
            _tracker(0, [2**64 - 1, *TRACKERS[0][1:]]),
            "OUT_OF_RANGE",
            "uint64 max",
            "trackers[0]",
        ),
        invalid(
            "frame_quat_nan",
            _tracker(1, [*TRACKERS[1][:6], float("nan")]),
            "OUT_OF_RANGE",
            "NaN w",
            "trackers[1]",
        ),
        invalid(
            "frame_quat_zero",
            _tracker(2, [*TRACKERS[2][:3], 0.0, 0.0, 0.0, 0.0]),
            "NOT_NORMALISED",
            "zero",
            "trackers[2]",
        ),
        invalid(
            "frame_quat_off",
            _tracker(0, [*TRACKERS[0][:3], 0.0, 0.0, 0.0, 1.0 + 2.0**-9]),
            "NOT_NORMALISED",
            "| |q| - 1 | = 1.95e-3 > 1e-3",
            "trackers[0]",
        ),
        invalid(
            "frame_quat_doubled",
            _tracker(3, [*TRACKERS[3][:3], 0.0, 2.0, 0.0, 0.0]),
            "NOT_NORMALISED",
            "|q| = 2",
            "trackers[3]",
        ),
        invalid("frame_valid_too_big", _frame_wire(valid=16), "OUT_OF_RANGE", "bit 4 set", "valid"),
        invalid("frame_valid_negative", _frame_wire(valid=-1), "OUT_OF_RANGE", "-1", "valid"),
        invalid("frame_valid_bool", _frame_wire(valid=True), "BAD_FIELD", "true", "valid"),
        invalid(
            "frame_huge_trackers",
            _frame_wire(trackers=[TRACKERS[0]] * 65),
            "TOO_LARGE",
            "65 trackers",
            None,
        ),
    ]


def _rest_positions(root: list[float]) -> Any:
    from posecast.skeleton import PARENTS, reference_offsets

    off = reference_offsets()
    p = np.zeros_like(off)
    p[0] = root
    for j in range(1, len(off)):
        p[j] = p[PARENTS[j]] + off[j]
    return p


def pose_cases() -> list[dict[str, Any]]:
    rest = _rest_positions([1.25, 0.96875, -2.5])
    rot = np.tile(ID_Q, (19, 1))
    rot[[4, 7, 10]] = HALF_Q
    rng = np.random.default_rng(2)
    moving = _rest_positions([3.317, 1.012, -0.482]) + rng.normal(scale=0.05, size=(19, 3))
    quats = rng.normal(size=(19, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    base = codec.to_wire(m.Pose("p-17", 9, 20.5, rest, rot))
    zero_rot = bytes(152)
    return [
        valid("pose_positions", m.Pose("p-17", 9, 20.5, rest), "the rest pose, positions only"),
        valid("pose_with_rotations", m.Pose("p-17", 9, 20.5, rest, rot), "with snorm16 rotations"),
        valid(
            "pose_realistic", m.Pose("p-3", 98765, 1712.125, moving, quats), "real-looking numbers"
        ),
        invalid(
            "pose_pos_short",
            {**base, "pos_mm": base["pos_mm"][:-1]},
            "BAD_FIELD",
            "107 bytes",
            "pos_mm",
        ),
        invalid(
            "pose_pos_array", {**base, "pos_mm": [0] * 54}, "BAD_FIELD", "ints, not a bin", "pos_mm"
        ),
        invalid(
            "pose_rot_zero",
            {**base, "rot": zero_rot},
            "NOT_NORMALISED",
            "all-zero rotations",
            "rot",
        ),
        invalid(
            "pose_root_nan",
            {**base, "root": [float("nan"), 0.0, 0.0]},
            "OUT_OF_RANGE",
            "NaN",
            "root",
        ),
        invalid("pose_root_two", {**base, "root": [0.0, 0.0]}, "BAD_FIELD", "2 numbers", "root"),
        invalid("pose_player_empty", {**base, "player": ""}, "OUT_OF_RANGE", "empty id", "player"),
    ]


def selector_cases() -> list[dict[str, Any]]:
    target = {
        "type": "selector",
        "player": "p-3",
        "kind": "target",
        "joint": "LEFT_HAND",
        "point": [0.5, 1.25, 0.75],
    }
    return [
        valid("selector_anomaly", m.Selector("p-3", "anomaly"), "back to the default selector"),
        valid("selector_anomaly_factor", m.Selector("p-3", "anomaly", factor=3.0), "with a factor"),
        valid(
            "selector_target",
            m.Selector("p-3", "target", "LEFT_HAND", (0.5, 1.25, 0.75), margin_m=0.03125),
            "reach a point with the left hand",
        ),
        valid(
            "selector_obstacle",
            m.Selector("p-3", "obstacle", "HEAD", (0.0, 1.75, 1.0), radius_m=0.25),
            "keep the head out of a sphere",
        ),
        invalid(
            "selector_kind_unknown", {**target, "kind": "magnet"}, "BAD_FIELD", "magnet", "kind"
        ),
        invalid(
            "selector_target_no_joint",
            {k: v for k, v in target.items() if k != "joint"},
            "BAD_FIELD",
            "no joint",
            "joint",
        ),
        invalid(
            "selector_joint_unknown",
            {**target, "joint": "LEFT_PAW"},
            "BAD_FIELD",
            "no such joint",
            "joint",
        ),
        invalid(
            "selector_joint_lower_case",
            {**target, "joint": "left_hand"},
            "BAD_FIELD",
            "names are upper case",
            "joint",
        ),
        invalid(
            "selector_point_short",
            {**target, "point": [0.5, 1.25]},
            "BAD_FIELD",
            "2 numbers",
            "point",
        ),
        invalid(
            "selector_point_absurd",
            {**target, "point": [0.5, 1e6, 0.0]},
            "OUT_OF_RANGE",
            "1e6 m",
            "point",
        ),
        invalid(
            "selector_radius_on_target",
            {**target, "radius_m": 0.25},
            "BAD_FIELD",
            "radius_m is for obstacles",
            "radius_m",
        ),
        invalid(
            "selector_radius_negative",
            {**target, "kind": "obstacle", "radius_m": -0.25},
            "OUT_OF_RANGE",
            "negative radius",
            "radius_m",
        ),
    ]
