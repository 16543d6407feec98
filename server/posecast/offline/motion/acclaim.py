"""Acclaim ASF/AMC reading (CMU's and HDM05's native motion-capture format).

An ASF file is the skeleton, an AMC file one take of motion on it. :func:`read_acclaim`
reads both and converts them to the :class:`~posecast.offline.motion.bvh.Bvh` that
:func:`~posecast.offline.motion.bvh.read_bvh` returns, so rig maps, retargeting and
resampling work on them unchanged. Files may be plain or gzip-compressed (detected by
content), with LF or CRLF line ends. Every problem raises
:class:`~posecast.errors.AcclaimError` naming the file and the line.

The convention (the one of CMU's own ASF/AMC viewer and of amc2bvh, which made the
cgspeed BVH release; fairmotion's ``asfamc`` loader reads it the same way):

* Order strings list rotations **in the order they are applied** to a vector, about
  fixed axes: ``axis 0 0 20 XYZ`` is ``C = Rz(20°) Ry(0) Rx(0)``, and ``dof rx ry rz``
  is ``M = Rz(rz) Ry(ry) Rx(rx)``. The ``axis`` values follow the letters of their
  order. A dof missing from a bone's list is a zero angle; a bone missing from a
  frame of the AMC holds zeros in that frame.
* ``C`` is the orientation of the bone's local frame in the world rest pose; the
  AMC values ``M`` turn the bone in that frame. In BVH terms (world rest
  rotations all identity) the bone's local rotation is ``L = C M C⁻¹``.
* ``direction`` is a unit vector in the world frame, so a bone starts where its
  parent ends: a joint's BVH offset is its **parent's** ``direction × length``; a
  leaf's own ``direction × length`` becomes its End Site.
* The root is a joint at ``position``; the AMC root line gives its values in the
  root ``order`` (``TX TY TZ RX RY RZ``): translation in length units, added to
  ``position``, and rotation applied RX first; ``orientation`` (in the root ``axis``
  order) plays the part of ``C`` for the root.
* ``:units length L`` means one length unit is ``(1 / L)`` inch: CMU and HDM05 say
  ``0.45``, 5.6444 cm. The result is in **metres** (its rig says ``unit_m: 1``).
  ``angle deg`` (the default) or ``rad``; an AMC ``:RADIANS`` or ``:DEGREES`` line
  overrides the ASF for that file's values.

The result has one joint per bone (``root`` first, then the ``:hierarchy`` depth
first), every joint with rotation channels ``Zrotation Yrotation Xrotation`` (the
root with ``Xposition Yposition Zposition`` before them), as amc2bvh writes. AMC
files store no frame rate; ``fps`` says it (CMU and HDM05: 120).

This module is the conversion; the parsers are :mod:`~posecast.offline.motion.acclaim_asf`
and :mod:`~posecast.offline.motion.acclaim_amc` (over
:mod:`~posecast.offline.motion.acclaim_text`), and their names stay importable here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from posecast.errors import AcclaimError
from posecast.geometry.rotations import axis_mat, mat2euler
from posecast.offline.motion.acclaim_amc import Amc, parse_amc, read_amc
from posecast.offline.motion.acclaim_asf import INCH_M, ROOT, Asf, AsfBone, parse_asf, read_asf
from posecast.offline.motion.bvh import Bvh, BvhJoint

__all__ = [  # the conversion, and the parsers' names kept importable from here
    "DEFAULT_FPS",
    "INCH_M",
    "ROOT",
    "Amc",
    "Asf",
    "AsfBone",
    "applied_rotation",
    "bone_axis_matrix",
    "parse_amc",
    "parse_asf",
    "read_acclaim",
    "read_amc",
    "read_asf",
    "to_bvh",
]

F64 = NDArray[np.float64]

DEFAULT_FPS = 120.0
_BVH_ROT = ("Zrotation", "Yrotation", "Xrotation")
_BVH_ROOT = ("Xposition", "Yposition", "Zposition", *_BVH_ROT)


def applied_rotation(angles: F64, axes: str) -> F64:
    """Rotations ``(..., 3, 3)`` applying ``angles (..., k)`` (radians) about ``axes`` in turn.

    ``axes="XYZ"`` gives ``Rz(a2) @ Ry(a1) @ Rx(a0)``: the first axis acts first. This is
    the Acclaim reading of both the ``axis ... XYZ`` lines and the ``dof`` lists.
    """
    out = np.broadcast_to(np.eye(3), (*angles.shape[:-1], 3, 3)).copy()
    for i, ax in enumerate(axes):
        out = axis_mat(ax, angles[..., i]) @ out
    return out


def bone_axis_matrix(bone: AsfBone, angle_unit: str) -> F64:
    """``C``: the bone's local frame in the world rest pose, ``(3, 3)``."""
    a = np.asarray(bone.axis, dtype=np.float64)
    if angle_unit == "deg":
        a = np.deg2rad(a)
    return applied_rotation(a, bone.axis_order)


def to_bvh(asf: Asf, amc: Amc, fps: float = DEFAULT_FPS) -> Bvh:
    """The :class:`Bvh` of ``amc`` on ``asf``: metres, ZYX rotation channels, ``fps``."""
    if not (fps > 0 and math.isfinite(fps)):
        raise AcclaimError(f"frame rate must be positive, got {fps}", file=amc.source)
    n_frames = amc.n_frames
    unit = asf.unit_m
    joints: list[BvhJoint] = []
    columns: list[F64] = []
    child_count = [0] * len(asf.bones)
    for b in asf.bones:
        if b.parent >= 0:
            child_count[b.parent] += 1
    for i, b in enumerate(asf.bones):
        if b.parent < 0:
            offset = tuple(v * unit for v in asf.position)
        else:
            p = asf.bones[b.parent]
            offset = tuple(d * p.length * unit for d in p.direction)
        end_site = None
        if child_count[i] == 0:
            end_site = tuple(d * b.length * unit for d in b.direction)
        is_root = b.parent < 0
        joints.append(
            BvhJoint(
                name=b.name,
                parent=b.parent,
                offset=offset,  # type: ignore[arg-type]
                channels=_BVH_ROOT if is_root else _BVH_ROT,
                end_site=end_site,  # type: ignore[arg-type]
                line=b.line,
            )
        )
        values = amc.values.get(b.name, np.zeros((n_frames, 0)))
        rot_idx = [k for k, d in enumerate(b.dof) if d.upper().startswith("R")]
        axes = "".join(b.dof[k][-1].upper() for k in rot_idx)
        if is_root:
            pos = np.zeros((n_frames, 3))
            for k, d in enumerate(b.dof):
                if d.startswith("T"):
                    pos[:, "XYZ".index(d[1])] = values[:, k] * unit
            columns.append(pos)
        if axes:
            ang = values[:, rot_idx]
            if not amc.radians:
                ang = np.deg2rad(ang)
            c = bone_axis_matrix(b, asf.angle_unit)
            local = c @ applied_rotation(ang, axes) @ c.T
            columns.append(np.rad2deg(mat2euler(local, "ZYX")))
        else:
            columns.append(np.zeros((n_frames, 3)))
    motion = np.concatenate(columns, axis=1) if n_frames else np.zeros((0, 3 * len(joints) + 3))
    return Bvh(tuple(joints), 1.0 / fps, motion, amc.source)


def read_acclaim(asf_path: str | Path, amc_path: str | Path, fps: float = DEFAULT_FPS) -> Bvh:
    """Read an ASF skeleton and an AMC take on it as a :class:`Bvh` (see the module doc)."""
    asf = read_asf(asf_path)
    return to_bvh(asf, read_amc(amc_path, asf), fps)
