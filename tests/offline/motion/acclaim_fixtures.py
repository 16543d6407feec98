"""Hand-made ASF/AMC files for the Acclaim tests (no ../shared data needed).

* ``GOLDEN_ASF`` / ``GOLDEN_AMC``: a root, a three-bone arm chain on a spine, and a stub
  with no dofs. Non-trivial ``axis`` lines (one of them in ZYX order) and dof lists
  out of the usual order (``rz rx``, ``ry rz rx``), so every part of the convention
  shows in the joint positions.
* :func:`cmu_like_asf` / :func:`cmu_like_amc`: a skeleton with the CMU / HDM05 bone
  names, axes and dofs (round-number bone directions and lengths, not any subject's)
  and a procedural walk on it, for the rig detection and ``data prepare`` tests.
"""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np

GOLDEN_ASF = """\
# golden fixture for tests/offline/motion/test_acclaim.py
:version 1.10
:name golden
:units
  mass 1.0
  length 0.45
  angle deg
:documentation
   A root, a spine, an arm of three bones and a stub with no dof.
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name spine
     direction 0 1 0
     length 2
     axis 0 0 0 XYZ
    dof rx ry rz
    limits (-30.0 30.0)
           (-30.0 30.0)
           (-30.0 30.0)
  end
  begin
     id 2
     name arm
     direction 1 0 0
     length 3
     axis 0 0 30 XYZ
    dof rz rx
    limits (-180.0 180.0)
           (-180.0 180.0)
  end
  begin
     id 3
     name forearm
     direction 0.6 0 -0.8
     length 2.5
     axis 90 -30 45 XYZ
    dof ry
    limits (-180.0 180.0)
  end
  begin
     id 4
     name hand
     direction 0 0 -1
     length 1
     axis 20 30 40 ZYX
    dof ry rz rx
    limits (-90.0 90.0)
           (-90.0 90.0)
           (-90.0 90.0)
  end
  begin
     id 5
     name stub
     direction 0 -1 0
     length 1.5
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root spine stub
    spine arm
    arm forearm
    forearm hand
  end
"""

# Frame 1: only the arm turns, rz 90 (and the root stands at (1, 2, 3)).
# Frame 2: only the root turns, RY 90.
# Frames 3-5: everything at once.
GOLDEN_AMC = """\
#!OML:ASF golden.asf
:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 0 0 0
spine 0 0 0
arm 90 0
forearm 0
hand 0 0 0
2
root 0 0 0 0 90 0
spine 0 0 0
arm 0 0
forearm 0
hand 0 0 0
3
root 0.5 17 -2 10 -20 30
spine 5 -10 15
arm 40 -25
forearm 70
hand 10 -20 30
4
root -1 16.5 4 -35 60 -15
spine -12 8 3
arm -60 45
forearm -110
hand -45 25 -5
5
root 2 17.2 1 170 -5 -175
spine 20 25 -30
arm 135 10
forearm 15
hand 80 -60 15
"""

GOLDEN_FRAMES = 5
UNIT_M = 0.0254 / 0.45


def write_text(path: Path, text: str, *, crlf: bool = False, gz: bool = False) -> Path:
    """Write ``text`` to ``path``, with CRLF line ends and/or gzip-compressed."""
    data = text.replace("\n", "\r\n") if crlf else text
    raw = data.encode("latin-1")
    if gz:
        raw = gzip.compress(raw, mtime=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(raw)
    return path


# --- a CMU-named skeleton -------------------------------------------------------------

_S20, _C20 = math.sin(math.radians(20)), math.cos(math.radians(20))

# name, parent, direction (left side; the right mirrors x), length, axis, dof
_LEFT = [
    ("hipjoint", "root", (0.6, -0.72, 0.35), 2.4, "0 0 0", ""),
    ("femur", "hipjoint", (_S20, -_C20, 0.0), 7.2, "0 0 20", "rx ry rz"),
    ("tibia", "femur", (_S20, -_C20, 0.0), 7.4, "0 0 20", "rx"),
    ("foot", "tibia", (0.07, -0.19, 0.98), 2.2, "-90 0 20", "rx rz"),
    ("toes", "foot", (0.0, 0.0, 1.0), 1.1, "-90 0 20", "rx"),
    ("clavicle", "thorax", (0.92, 0.39, 0.05), 3.5, "0 0 0", "ry rz"),
    ("humerus", "clavicle", (1.0, 0.0, 0.0), 5.4, "180 -30 -90", "rx ry rz"),
    ("radius", "humerus", (1.0, 0.0, 0.0), 3.2, "180 -30 -90", "rx"),
    ("wrist", "radius", (1.0, 0.0, 0.0), 1.6, "0 90 90", "ry"),
    ("hand", "wrist", (1.0, 0.0, 0.0), 0.7, "0 90 90", "rx rz"),
    ("fingers", "hand", (1.0, 0.0, 0.0), 0.6, "0 90 90", "rx"),
    ("thumb", "wrist", (0.7071, 0.0, 0.7071), 0.8, "-90 45 0", "rx rz"),
]
_CENTRE = [
    ("lowerback", "root", (0.0, 1.0, -0.05), 2.1, "0 0 0", "rx ry rz"),
    ("upperback", "lowerback", (0.0, 1.0, 0.05), 2.1, "0 0 0", "rx ry rz"),
    ("thorax", "upperback", (0.0, 1.0, 0.1), 2.1, "0 0 0", "rx ry rz"),
    ("lowerneck", "thorax", (0.0, 1.0, 0.05), 1.8, "0 0 0", "rx ry rz"),
    ("upperneck", "lowerneck", (0.0, 1.0, -0.05), 1.8, "0 0 0", "rx ry rz"),
    ("head", "upperneck", (0.0, 1.0, 0.0), 1.9, "0 0 0", "rx ry rz"),
]


def _mirror_axis(axis: str) -> str:
    x, y, z = (float(v) for v in axis.split())
    return f"{x:g} {-y:g} {-z:g}"


def cmu_bones() -> list[tuple[str, str, tuple[float, float, float], float, str, str]]:
    """The CMU bones in ASF order: legs, spine, arms."""
    bones = []
    for side in "lr":
        for name, parent, d, length, axis, dof in _LEFT[:5]:
            p = parent if parent == "root" else side + parent
            dd = d if side == "l" else (-d[0], d[1], d[2])
            ax = axis if side == "l" else _mirror_axis(axis)
            bones.append((side + name, p, dd, length, ax, dof))
    bones += _CENTRE
    for side in "lr":
        for name, parent, d, length, axis, dof in _LEFT[5:]:
            p = parent if parent == "thorax" else side + parent
            dd = d if side == "l" else (-d[0], d[1], d[2])
            ax = axis if side == "l" else _mirror_axis(axis)
            bones.append((side + name, p, dd, length, ax, dof))
    return bones


def cmu_like_asf(name: str = "fixture") -> str:
    out = [
        "# AST/ASF file, CMU bone names, made by the posecast tests",
        ":version 1.10",
        f":name {name}",
        ":units",
        "  mass 1.0",
        "  length 0.45",
        "  angle deg",
        ":documentation",
        "   procedural",
        ":root",
        "   order TX TY TZ RX RY RZ",
        "   axis XYZ",
        "   position 0 0 0",
        "   orientation 0 0 0",
        ":bonedata",
    ]
    for i, (bone, _, d, length, axis, dof) in enumerate(cmu_bones(), start=1):
        out += [
            "  begin",
            f"     id {i}",
            f"     name {bone}",
            f"     direction {d[0]:.6g} {d[1]:.6g} {d[2]:.6g}",
            f"     length {length:g}",
            f"     axis {axis} XYZ",
        ]
        if dof:
            out.append(f"    dof {dof}")
            out.append("    limits " + "\n           ".join(["(-180.0 180.0)"] * len(dof.split())))
        out.append("  end")
    out += [":hierarchy", "  begin"]
    children: dict[str, list[str]] = {}
    for bone, parent, *_ in cmu_bones():
        children.setdefault(parent, []).append(bone)
    out += [f"    {p} {' '.join(c)}" for p, c in children.items()]
    out += ["  end", ""]
    return "\n".join(out)


def cmu_like_amc(seconds: float = 1.0, fps: float = 120.0, seed: int = 0) -> str:
    """A walk along +Z on :func:`cmu_like_asf`, every bone in every frame."""
    rng = np.random.default_rng(seed)
    n = max(2, round(seconds * fps))
    t = np.arange(n) / fps
    hz = rng.uniform(0.8, 1.1)
    ph = 2 * np.pi * hz * t
    unit = 0.0254 / 0.45
    lines = ["#!OML:ASF fixture.asf", ":FULLY-SPECIFIED", ":DEGREES"]
    for i in range(n):
        s, c = math.sin(ph[i]), math.cos(ph[i])
        z = 1.1 * t[i] / unit
        vals: dict[str, list[float]] = {
            "root": [0.3 * s, 16.8 + 0.2 * c * c, z, -3 + 2 * c, 5 * math.sin(0.3 * t[i]), s],
            "lowerback": [4 + s, 0.5 * s, 0.3 * c],
            "upperback": [1, -2 * s, 0.5],
            "thorax": [-1, -2 * s, 0.2],
            "lowerneck": [-5, 1, 0],
            "upperneck": [6, -1, 0.5 * s],
            "head": [2, 3 * math.sin(0.5 * t[i]), 0],
        }
        for side, sign in (("l", 1.0), ("r", -1.0)):
            sw = sign * s
            vals[side + "femur"] = [-20 * sw - 5, 2 * sign, 4 * sign]
            vals[side + "tibia"] = [15 + 25 * max(0.0, -sw)]
            vals[side + "foot"] = [-8 + 10 * sw, 3 * sign]
            vals[side + "toes"] = [-5 * max(0.0, sw)]
            vals[side + "clavicle"] = [0.0, 0.0]
            vals[side + "humerus"] = [30 * sw, 5 * sign, 75 * sign]
            vals[side + "radius"] = [25 + 10 * max(0.0, sw)]
            vals[side + "wrist"] = [10 * sign]
            vals[side + "hand"] = [-10, 5 * sign]
            vals[side + "fingers"] = [7.0]
            vals[side + "thumb"] = [5, 20 * sign]
        lines.append(str(i + 1))
        lines += [f"{k} " + " ".join(f"{v:.6f}" for v in vs) for k, vs in vals.items()]
    return "\n".join(lines) + "\n"
