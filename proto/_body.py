"""``skeleton.md`` and ``skeleton.json``: the body the wire speaks of, from the server's sources.

Used by ``generate_spec.py``. Everything in the tables comes from the modules the
server runs (and the SDKs' tests compare their own copies with): the joints, parents,
rest offsets and landmarks from ``posecast.skeleton``, the tracker slots and sites from
``posecast.tracking``, the reference body's heights and the calibration rules from
``posecast.online.engine.calibration``, the reference ``skeleton`` bin from
``posecast.online.protocol.records``. Only the prose around them is written here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from posecast.online.engine import calibration as cal
from posecast.online.protocol import records
from posecast.skeleton import (
    LANDMARK,
    PARENT,
    REST_PELVIS_HEIGHT_M,
    REST_TOE_HEIGHT_M,
    Joint,
    children,
    reference_offsets,
)
from posecast.tracking.features import TRACKER_JOINT, TrackerSlot
from posecast.tracking.layouts import SPECS, Layout
from posecast.tracking.sites import INERTIAL_SUFFIX, REQUIRED, SITE_JOINT, SITES

# A joint's own axes, as its world rotation maps them: at the identity they are the
# world's, and the body stands in its rest pose facing +Z (posecast.skeleton).
AXES = {"+X": "the body's left", "+Y": "up", "+Z": "forward (the way the body faces)"}
_DEVICE = {
    TrackerSlot.HEAD: "headset",
    TrackerSlot.LEFT_HAND: "left controller",
    TrackerSlot.RIGHT_HAND: "right controller",
    TrackerSlot.WAIST: "waist tracker",
}
_WORDS = {(0, 1): "+X", (0, -1): "-X", (1, 1): "+Y", (1, -1): "-Y", (2, 1): "+Z", (2, -1): "-Z"}


def _r(x: float) -> float:
    return round(float(x), 6) + 0.0  # + 0.0: no -0.0


def rest_positions() -> np.ndarray:
    """``(19, 3)`` world positions of the reference body in its rest pose, feet down."""
    off = reference_offsets()
    pos = np.zeros_like(off)
    for j in Joint:
        parent = PARENT[j]
        pos[j] = off[j] + (pos[parent] if parent is not None else (0.0, REST_PELVIS_HEIGHT_M, 0.0))
    return pos


def bone(j: Joint) -> tuple[str, list[float]]:
    """The bone a joint's rotation turns, and its rest direction: to its first child, or
    (a leaf) from its parent."""
    off = reference_offsets()
    kids = children(j)
    if kids:
        what, vec = f"{j.name} to {kids[0].name}", off[kids[0]]
    else:
        parent = PARENT[j]
        assert parent is not None
        what, vec = f"{parent.name} to {j.name}", off[j]
    unit = vec / np.linalg.norm(vec)
    return what, [_r(v) for v in np.round(unit, 3)]


def direction(unit: list[float], md: bool = False) -> str:
    """``+X`` for an axis, else the vector; ``md``: with a typographic minus."""
    nz = [i for i, v in enumerate(unit) if v != 0.0]
    if len(nz) == 1:
        out = _WORDS[(nz[0], 1 if unit[nz[0]] > 0 else -1)]
    else:
        out = "(" + ", ".join(f"{v:.2f}" for v in unit) + ")"
    return out.replace("-", "−") if md else out


def body_json() -> dict[str, Any]:
    off, pos = reference_offsets(), rest_positions()
    head_top = cal.REFERENCE_HEAD_HEIGHT_M + cal.HEAD_TOP_ABOVE_JOINT_M
    joints = []
    for j in Joint:
        parent = PARENT[j]
        what, unit = bone(j)
        joints.append(
            {
                "index": int(j),
                "name": j.name,
                "parent": None if parent is None else parent.name,
                "parent_index": -1 if parent is None else int(parent),
                "offset_m": [_r(v) for v in off[j]],
                "rest_position_m": [_r(v) for v in pos[j]],
                "landmark": LANDMARK[j],
                "bone": what,
                "bone_direction_at_rest": unit,
            }
        )
    return {
        "$comment": (
            "The posecast body: joints, the reference body, tracker slots and sites, device"
            " frames. Written by proto/generate_spec.py from server/posecast/skeleton.py and"
            " server/posecast/tracking/: do not edit. Described in skeleton.md."
        ),
        "units": {"length": "m", "quaternion": "xyzw"},
        "world": {
            "handedness": "right",
            "up": "+Y",
            "forward": "+Z",
            "left": "+X",
            "floor_y_m": 0.0,
        },
        "joint_axes_at_identity": AXES,
        "joints": joints,
        "reference_body": {
            "height_m": _r(head_top),
            "head_joint_height_m": _r(cal.REFERENCE_HEAD_HEIGHT_M),
            "head_top_above_head_joint_m": _r(cal.HEAD_TOP_ABOVE_JOINT_M),
            "pelvis_height_m": _r(REST_PELVIS_HEIGHT_M),
            "toe_height_m": _r(REST_TOE_HEIGHT_M),
            "rest_pose": (
                "T-pose facing +Z: arms along +-X, palms down, legs straight down,"
                " every local rotation the identity"
            ),
            "skeleton_bin": records.skeleton2bytes(records.skeleton_offsets(1.0)).hex(),
        },
        "tracker_slots": [
            {
                "slot": int(s),
                "name": s.name,
                "device": _DEVICE[s],
                "joint": TRACKER_JOINT[s].name,
                "layouts": [
                    lay.value for lay in (Layout.HMD3_WAIST, Layout.HMD3) if s in SPECS[lay].slots
                ],
            }
            for s in TrackerSlot
        ],
        "sites": [
            {
                "row": i,
                "name": site.value,
                "joint": SITE_JOINT[site].name,
                "required": site in REQUIRED,
                "inertial_allowed": site not in REQUIRED,
            }
            for i, site in enumerate(SITES)
        ],
        "inertial_suffix": INERTIAL_SUFFIX,
        "calibration": {
            "height_m": [cal.MIN_HEIGHT_M, cal.MAX_HEIGHT_M],
            "scale_from_height": "reference_body.height_m / height_m",
            "scale_from_tpose": "reference_body.head_joint_height_m / head tracker y",
            "tpose_head_y_m_exclusive": [
                _r(cal.MIN_HEIGHT_M - cal.HEAD_TOP_ABOVE_JOINT_M),
                cal.MAX_HEIGHT_M,
            ],
            "tpose_min_hand_span_m": cal.MIN_TPOSE_HAND_SPAN_M,
        },
    }


def _v(xs: list[float]) -> str:
    return "(" + ", ".join(f"{x:.2f}".replace("-", "−") for x in xs) + ")"


def body_md(data: dict[str, Any]) -> str:
    ref = data["reference_body"]
    cal_ = data["calibration"]
    lines = [
        "# The posecast body: skeleton, trackers and device frames",
        "",
        "<!-- Written by proto/generate_spec.py from server/posecast/skeleton.py and",
        "     server/posecast/tracking/ (the same tables the server runs): do not edit.",
        "     skeleton.json holds the same tables for programs. -->",
        "",
        "This page is part of the wire spec ([README.md](README.md)): every joint a pose",
        "names, every tracker a frame carries, and the frame each quaternion is in.",
        "",
        "## Conventions",
        "",
        "| what | convention |",
        "|---|---|",
        "| units | metres, seconds |",
        "| world | right-handed, **+Y up**; the floor is `y = 0` |",
        "| facing | a body in its rest pose faces **+Z**; its left is **+X**, its right −X |",
        "| quaternions | **xyzw**, scalar last; a rotation `q` maps a vector `v` of the"
        " object's own frame to the world: `v_world = R(q) @ v` |",
        "| rest pose | every local rotation the identity: a **T-pose**, arms along ±X,"
        " palms down, legs straight down |",
        "| forward kinematics | `p[j] = p[parent] + R(world[parent]) @ offset[j]`,"
        " `world[j] = world[parent] * local[j]` (Hamilton product) |",
        "| joint names | upper-case strings on the wire, never indices |",
        "",
        "## Joints",
        "",
        "Joint indices are topological: every parent comes before its children. Arrays of",
        "joints on the wire (`pos_mm`, `rot`, pose records, `skeleton`) follow this order.",
        "The offset is the rest-pose vector from the parent; the rest position is where the",
        f"joint stands with the pelvis at {ref['pelvis_height_m']:.2f} m and the feet on the"
        " floor.",
        "",
        "| # | joint | parent | rest offset (m) | rest position (m) | where on the body |",
        "|---:|---|---|---|---|---|",
    ]
    for j in data["joints"]:
        parent = f"`{j['parent']}`" if j["parent"] else "—"
        lines.append(
            f"| {j['index']} | `{j['name']}` | {parent} | {_v(j['offset_m'])} | "
            f"{_v(j['rest_position_m'])} | {j['landmark']} |"
        )
    lines += [
        "",
        "Parent indices, in joint order (−1 for the root):",
        "",
        "```",
        "[" + ", ".join(str(j["parent_index"]) for j in data["joints"]) + "]",
        "```",
        "",
        "## The reference body",
        "",
        f"The networks were trained on one body, **{ref['height_m']:.2f} m** tall, standing in",
        "the rest pose (the T-pose above): the `HEAD` joint at"
        f" **{ref['head_joint_height_m']:.2f} m**",
        f"(the headset's height), the top of the head {ref['head_top_above_head_joint_m']:.2f} m",
        f"above it, the `PELVIS` at **{ref['pelvis_height_m']:.2f} m**, the toe joints",
        f"{ref['toe_height_m']:.2f} m above the floor with the feet flat.",
        "Calibration ([below](#calibration)) scales every player onto it. Its `skeleton` bin",
        "(v2; 18 × 3 int16 LE in 0.1 mm, the offsets of `SPINE` … `RIGHT_TOE`):",
        "",
        "```",
    ]
    hex_ = ref["skeleton_bin"]
    lines += [hex_[i : i + 72] for i in range(0, len(hex_), 72)]
    lines += [
        "```",
        "",
        "## Tracker slots",
        "",
        "The `trackers` of a `frame` (layouts `hmd3+waist` and `hmd3`) are four rows in this",
        "order. Each drives one joint: the row's position is where that joint is, and its",
        "quaternion is that joint's world rotation ([Device frames](#device-frames)).",
        "",
        "| slot | name | device | joint | where on the body | layouts that read it |",
        "|---:|---|---|---|---|---|",
    ]
    land = {j["name"]: j["landmark"] for j in data["joints"]}
    for s in data["tracker_slots"]:
        lines.append(
            f"| {s['slot']} | `{s['name']}` | {s['device']} | `{s['joint']}` | "
            f"{land[s['joint']]} | " + ", ".join(f"`{x}`" for x in s["layouts"]) + " |"
        )
    lines += [
        "",
        "So `HEAD` is the headset's own position, with no eye or neck offset, and `PELVIS`",
        "the waist tracker's (an `hmd3+waist` T-pose `calibrate` measures where the tracker",
        "sits from the pelvis, in the tracker's own frame, and takes that off every later",
        "frame). An `hmd3` player's waist slot is ignored: the model places the pelvis.",
        "",
        "## Tracker-set sites",
        "",
        "A tracker set (`hello.layout` such as `head,left_hand,right_hand,left_foot:imu`)",
        "sends one `sites` row per site it lists, in the order it lists them. A positional",
        "site's row is the joint's position and world rotation; an inertial site's",
        f"(suffix `{data['inertial_suffix']}`) is its world-frame linear acceleration, gravity",
        "removed, in m/s², and its world rotation.",
        "",
        "| model row | site | joint | where on the body | rotation of the bone | required |",
        "|---:|---|---|---|---|---|",
    ]
    bones = {j["name"]: j["bone"] for j in data["joints"]}
    for s in data["sites"]:
        req = "yes, positional" if s["required"] else "no; positional or inertial"
        lines.append(
            f"| {s['row']} | `{s['name']}` | `{s['joint']}` | {land[s['joint']]} | "
            f"{bones[s['joint']]} | {req} |"
        )
    lines += [
        "",
        "The model row is the site's place in the model's input, not on the wire: the wire",
        "order is the set's. A knee tracker is strapped below the knee and reports the shin's",
        "rotation; an elbow tracker reports the forearm's.",
        "",
        "## Device frames",
        "",
        "A tracker's quaternion is the **world rotation of the joint it drives**: it maps",
        "that joint's own axes to the world's. Every joint's own axes are the world's when",
        "the body stands in the rest pose, so at the **identity quaternion**:",
        "",
        "| axis | points |",
        "|---|---|",
    ]
    lines += [f"| {axis} | {words} |" for axis, words in data["joint_axes_at_identity"].items()]
    lines += [
        "",
        "and each device lies as its joint does in the T-pose:",
        "",
        "| device | joint | its bone at the identity | so, at the identity |",
        "|---|---|---|---|",
    ]
    looks = {
        "HEAD": "the headset looks along +Z, its top up (+Y), its left side +X",
        "LEFT_HAND": "the hand points along the arm to +X, palm down (−Y), thumb forward (+Z)",
        "RIGHT_HAND": "the hand points along the arm to −X, palm down (−Y), thumb forward (+Z)",
        "PELVIS": "the tracker's front faces +Z, up is +Y",
        "LEFT_FOOT": "the foot points forward and down to the toes, sole down",
        "RIGHT_FOOT": "the foot points forward and down to the toes, sole down",
        "LEFT_SHIN": "the shin points straight down, its front +Z",
        "RIGHT_SHIN": "the shin points straight down, its front +Z",
        "LEFT_FOREARM": "the forearm points along the arm to +X, palm down",
        "RIGHT_FOREARM": "the forearm points along the arm to −X, palm down",
    }
    joints = {j["name"]: j for j in data["joints"]}
    rows = [(s["device"], s["joint"]) for s in data["tracker_slots"]]
    rows += [(f"`{s['name']}` site", s["joint"]) for s in data["sites"] if not s["required"]]
    for device, jname in rows:
        if device == "`waist` site":
            continue  # the waist tracker's row above
        j = joints[jname]
        lines.append(
            f"| {device} | `{jname}` | {j['bone']}: "
            f"{direction(j['bone_direction_at_rest'], md=True)} | "
            f"{looks[jname]} |"
        )
    lines += [
        "",
        "A device whose own axes differ (every real headset and controller: WebXR's viewer",
        "looks along −Z, a controller's grip axes are its runtime's) is converted before",
        "sending, `q_joint = q_device * q_offset` with the device's fixed offset on the",
        "right. For WebXR that offset is a half turn about Y, `(0, 1, 0, 0)`, for every",
        "device (the TypeScript SDK's `xrToPosecast`). What the server does with what is",
        "left of the offset:",
        "",
        "* `hmd3` and tracker sets: a T-pose `calibrate` measures each device's remaining",
        "  offset (in a T-pose every joint's world rotation is the body's heading) and takes",
        "  it off every later frame, so any fixed grip works once calibrated.",
        "* `hmd3+waist`: no rotation offsets are measured. The head and hands are shown",
        "  with the headset's and controllers' rotations as sent, the elbows are placed",
        "  from the controllers' rotations, and the pelvis takes the waist tracker's.",
        "",
        "## Calibration",
        "",
        "Calibration scales a player onto the reference body: positions are multiplied by",
        "the **scale** (reference metres per player metre) on the way in, and divided by it",
        "on the way out, so the avatar stands where the player stands, at the player's size.",
        "",
        f"* `height_m` ({cal_['height_m'][0]} to {cal_['height_m'][1]} m, floor to the top of the"
        f" head): scale = {ref['height_m']:.2f} / `height_m`.",
        "* T-pose (`tpose: true` and one frame of trackers or sites, every row tracked):"
        f" scale = {ref['head_joint_height_m']:.2f} / the head tracker's y.",
        "  `CALIBRATION_FAILED` when the head's y is not strictly between"
        f" {cal_['tpose_head_y_m_exclusive'][0]} and {cal_['tpose_head_y_m_exclusive'][1]} m,",
        f"  or the hands are less than {cal_['tpose_min_hand_span_m']} m apart horizontally"
        " (the heading is square to the line between them).",
        "",
        "In v2 an avatar's `skeleton` is the reference offsets divided by its scale, sent",
        "(`skeleton` message) only when a calibration **changes** the scale. Every player",
        f"starts at scale 1, so a player who calibrates to {ref['height_m']:.2f} m gets no"
        " `skeleton` message: the scale stays 1.",
        "",
    ]
    return "\n".join(lines)
