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
"""

from __future__ import annotations

import gzip
import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from posecast.errors import AcclaimError
from posecast.geometry.rotations import axis_mat, mat2euler
from posecast.offline.motion.bvh import Bvh, BvhJoint

F64 = NDArray[np.float64]

INCH_M = 0.0254
DEFAULT_FPS = 120.0
ROOT = "root"
_ROT_DOFS = ("rx", "ry", "rz")
_ROOT_CHANNELS = ("TX", "TY", "TZ", "RX", "RY", "RZ")
_BVH_ROT = ("Zrotation", "Yrotation", "Xrotation")
_BVH_ROOT = ("Xposition", "Yposition", "Zposition", *_BVH_ROT)


@dataclass(frozen=True)
class AsfBone:
    """One ASF bone (or the root), in :attr:`Asf.bones` order (parents first)."""

    name: str
    parent: int  # index into Asf.bones, -1 for the root
    direction: tuple[float, float, float]  # unit vector, world rest frame
    length: float  # file length units
    axis: tuple[float, float, float]  # degrees or radians (Asf.angle_unit), in axis_order
    axis_order: str  # e.g. "XYZ": the order the axis rotations are applied in
    dof: tuple[str, ...]  # e.g. ("rx", "ry", "rz"); root: its :root order, upper case
    line: int  # 1-based line of its ``begin`` (the root: of ``:root``)


@dataclass(frozen=True)
class Asf:
    """A parsed ASF skeleton."""

    name: str
    unit_m: float  # metres per length unit
    angle_unit: str  # "deg" or "rad"
    position: tuple[float, float, float]  # root rest position, length units
    bones: tuple[AsfBone, ...]
    source: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bones)

    def index(self, name: str) -> int:
        return self.names.index(name)


@dataclass(frozen=True)
class Amc:
    """A parsed AMC take: per bone, its dof values in the ASF's dof order."""

    values: dict[str, F64]  # bone name -> (F, len(dof)); absent bones are zeros
    frame_numbers: NDArray[np.int64]
    radians: bool
    source: str

    @property
    def n_frames(self) -> int:
        return int(self.frame_numbers.shape[0])


# --- reading text ----------------------------------------------------------------------


def _read_lines(path: str | Path) -> list[str]:
    """The lines of a text file, plain or gzip, any line ends (AcclaimError if unreadable)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise AcclaimError(f"cannot read file: {exc.strerror or exc}", file=p) from exc
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as exc:
            raise AcclaimError(f"corrupt gzip stream: {exc}", file=p) from exc
    if b"\x00" in raw:
        raise AcclaimError(
            "not a text file", file=p, line=raw[: raw.index(b"\x00")].count(b"\n") + 1
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # HDM05 comments carry Latin-1 path names
    # LF, CRLF or CR; not str.splitlines, which also breaks at Latin-1's NEL (0x85) and
    # would put every later line number off.
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if lines and not lines[-1]:
        lines.pop()
    return lines


def _floats(tokens: Sequence[str], n: int, what: str, source: str, line: int) -> list[float]:
    if len(tokens) != n:
        raise AcclaimError(
            f"{what}: expected {n} number(s), found {len(tokens)}", file=source, line=line
        )
    try:
        out = [float(t) for t in tokens]
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise AcclaimError(f"{what}: {bad!r} is not a number", file=source, line=line) from None
    if not all(math.isfinite(v) for v in out):
        raise AcclaimError(f"{what}: non-finite value", file=source, line=line)
    return out


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def _order(text: str, source: str, line: int) -> str:
    order = text.upper()
    if len(order) != 3 or set(order) != set("XYZ"):
        raise AcclaimError(f"bad axis order {text!r} (want e.g. XYZ)", file=source, line=line)
    return order


# --- ASF -------------------------------------------------------------------------------


def read_asf(path: str | Path) -> Asf:
    """Read an ASF (or ``.asx``) skeleton, plain or gzip-compressed."""
    return parse_asf(_read_lines(path), source=str(path))


@dataclass
class _Bone:
    line: int
    name: str | None = None
    direction: tuple[float, float, float] | None = None
    length: float | None = None
    axis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis_order: str = "XYZ"
    dof: tuple[str, ...] = ()


def parse_asf(lines: Sequence[str], source: str = "<string>") -> Asf:
    """Parse ASF text split into lines. ``source`` names the file in error messages."""
    rows = [(n, ln.split()) for n, ln in enumerate(lines, start=1)]
    rows = [(n, t) for n, t in rows if t and not t[0].startswith("#")]
    if not rows:
        raise AcclaimError("not an ASF file (empty)", file=source, line=1)
    if not rows[0][1][0].startswith(":"):
        raise AcclaimError(
            f"not an ASF file (starts with {rows[0][1][0]!r}, not a :keyword)",
            file=source,
            line=rows[0][0],
        )
    name = ""
    length_unit = 1.0
    angle_unit = "deg"
    root_order: tuple[str, ...] = _ROOT_CHANNELS
    root_axis = "XYZ"
    position = (0.0, 0.0, 0.0)
    orientation = (0.0, 0.0, 0.0)
    root_line: int | None = None
    bones: list[_Bone] = []
    hierarchy: list[tuple[int, list[str]]] = []
    have_hierarchy = False
    section = ""
    current: _Bone | None = None
    in_hier_block = False
    for n, tok in rows:
        key = tok[0]
        if key.startswith(":"):
            if current is not None:
                raise AcclaimError(
                    f"bone block from line {current.line} has no 'end'", file=source, line=n
                )
            section = key.lower()
            if section == ":name" and len(tok) > 1:
                name = " ".join(tok[1:])
            elif section == ":root":
                root_line = n
            elif section == ":hierarchy":
                have_hierarchy = True
            elif section == ":units" and len(tok) > 1:
                # some writers put "length 0.45" on the :units line itself
                length_unit, angle_unit = _unit_entry(tok[1:], length_unit, angle_unit, source, n)
            continue
        low = key.lower()
        if section == ":units":
            length_unit, angle_unit = _unit_entry(tok, length_unit, angle_unit, source, n)
        elif section == ":root":
            if low == "order":
                root_order = tuple(t.upper() for t in tok[1:])
                bad = [t for t in root_order if t not in _ROOT_CHANNELS]
                if bad or len(set(root_order)) != len(root_order):
                    raise AcclaimError(
                        f"bad root order {' '.join(tok[1:])!r} (want e.g. TX TY TZ RX RY RZ)",
                        file=source,
                        line=n,
                    )
            elif low == "axis":
                if len(tok) != 2:
                    raise AcclaimError(
                        "root axis: expected one order, e.g. XYZ", file=source, line=n
                    )
                root_axis = _order(tok[1], source, n)
            elif low == "position":
                position = tuple(_floats(tok[1:], 3, "root position", source, n))  # type: ignore[assignment]
            elif low == "orientation":
                orientation = tuple(_floats(tok[1:], 3, "root orientation", source, n))  # type: ignore[assignment]
            else:
                raise AcclaimError(f"unknown :root entry {key!r}", file=source, line=n)
        elif section == ":bonedata":
            if low == "begin":
                if current is not None:
                    raise AcclaimError(
                        f"'begin' inside the bone block of line {current.line}", file=source, line=n
                    )
                current = _Bone(line=n)
            elif current is None:
                raise AcclaimError(f"expected 'begin', found {key!r}", file=source, line=n)
            elif low == "end":
                bones.append(_finish_bone(current, source, n))
                current = None
            else:
                _bone_entry(current, low, tok, source, n)
        elif section == ":hierarchy":
            if low == "begin":
                in_hier_block = True
            elif low == "end":
                in_hier_block = False
            elif not in_hier_block:
                raise AcclaimError(f"expected 'begin', found {key!r}", file=source, line=n)
            else:
                hierarchy.append((n, tok))
        # other sections (:version, :documentation, :skin, ...) are ignored
    if current is not None:
        raise AcclaimError(
            f"bone block from line {current.line} has no 'end'", file=source, line=rows[-1][0]
        )
    if root_line is None:
        raise AcclaimError("not an ASF file (no :root section)", file=source, line=rows[-1][0])
    if not have_hierarchy:
        raise AcclaimError("no :hierarchy section (file truncated?)", file=source, line=rows[-1][0])
    if in_hier_block:
        raise AcclaimError("the :hierarchy block has no 'end'", file=source, line=rows[-1][0])
    root = _Bone(
        line=root_line,
        name=ROOT,
        direction=(0.0, 0.0, 0.0),
        length=0.0,
        axis=orientation,
        axis_order=root_axis,
        dof=root_order,
    )
    ordered = _topological(root, bones, hierarchy, source)
    if length_unit <= 0:
        raise AcclaimError("':units length' must be positive", file=source)
    return Asf(
        name=name,
        unit_m=INCH_M / length_unit,
        angle_unit=angle_unit,
        position=position,
        bones=ordered,
        source=source,
    )


def _unit_entry(
    tok: Sequence[str], length_unit: float, angle_unit: str, source: str, n: int
) -> tuple[float, str]:
    key = tok[0].lower()
    if key == "length":
        (length_unit,) = _floats(tok[1:], 1, "units length", source, n)
        if length_unit <= 0:
            raise AcclaimError("units length must be positive", file=source, line=n)
    elif key == "angle":
        unit = tok[1].lower() if len(tok) == 2 else ""
        if unit not in ("deg", "rad"):
            raise AcclaimError(
                f"units angle must be 'deg' or 'rad', found {' '.join(tok[1:])!r}",
                file=source,
                line=n,
            )
        angle_unit = unit
    # mass and anything else: not needed
    return length_unit, angle_unit


def _bone_entry(bone: _Bone, key: str, tok: Sequence[str], source: str, n: int) -> None:
    if key == "name":
        if len(tok) != 2:
            raise AcclaimError("name: expected one word", file=source, line=n)
        bone.name = tok[1]
    elif key == "direction":
        d = _floats(tok[1:], 3, "direction", source, n)
        norm = math.sqrt(sum(v * v for v in d))
        bone.direction = (
            (d[0] / norm, d[1] / norm, d[2] / norm) if norm > 1e-12 else (0.0, 0.0, 0.0)
        )
    elif key == "length":
        (bone.length,) = _floats(tok[1:], 1, "length", source, n)
        if bone.length < 0:
            raise AcclaimError("length must be >= 0", file=source, line=n)
    elif key == "axis":
        if len(tok) != 5:
            raise AcclaimError(
                "axis: expected three angles and an order, e.g. 'axis 0 0 20 XYZ'",
                file=source,
                line=n,
            )
        bone.axis = tuple(_floats(tok[1:4], 3, "axis", source, n))  # type: ignore[assignment]
        bone.axis_order = _order(tok[4], source, n)
    elif key == "dof":
        dof = tuple(t.lower() for t in tok[1:])
        bad = [t for t in dof if t not in _ROT_DOFS]
        if bad:
            what = (
                "translation/length dofs on a bone are not supported"
                if all(t in ("tx", "ty", "tz", "l") for t in bad)
                else "unknown dof"
            )
            raise AcclaimError(f"{what}: {' '.join(bad)}", file=source, line=n)
        if len(set(dof)) != len(dof):
            raise AcclaimError("dof lists an axis twice", file=source, line=n)
        bone.dof = dof
    # id, limits (and their continuation lines), bodymass, cofmass: not needed


def _finish_bone(bone: _Bone, source: str, n: int) -> _Bone:
    for field_name in ("name", "direction", "length"):
        if getattr(bone, field_name) is None:
            raise AcclaimError(
                f"bone block from line {bone.line} has no {field_name!r}", file=source, line=n
            )
    if bone.name == ROOT:
        raise AcclaimError("a bone may not be called 'root'", file=source, line=bone.line)
    return bone


def _topological(
    root: _Bone, bones: list[_Bone], hierarchy: list[tuple[int, list[str]]], source: str
) -> tuple[AsfBone, ...]:
    by_name: dict[str, _Bone] = {ROOT: root}
    for b in bones:
        assert b.name is not None
        if b.name in by_name:
            raise AcclaimError(f"duplicate bone name {b.name!r}", file=source, line=b.line)
        by_name[b.name] = b
    children: dict[str, list[str]] = {k: [] for k in by_name}
    parent_of: dict[str, str] = {}
    for n, tok in hierarchy:
        for nm in tok:
            if nm not in by_name:
                raise AcclaimError(
                    f"hierarchy names {nm!r}, which is not a bone", file=source, line=n
                )
        for child in tok[1:]:
            if child == ROOT or child in parent_of:
                raise AcclaimError(f"bone {child!r} is given a second parent", file=source, line=n)
            parent_of[child] = tok[0]
            children[tok[0]].append(child)
    order: list[str] = []
    stack = [ROOT]
    while stack:
        nm = stack.pop()
        if nm in order:  # pragma: no cover - a second parent is caught above
            continue
        order.append(nm)
        stack.extend(reversed(children[nm]))
    unplaced = [b for b in bones if b.name not in order]
    if unplaced:
        b = unplaced[0]
        raise AcclaimError(
            f"bone {b.name!r} is not reachable from the root in :hierarchy",
            file=source,
            line=b.line,
        )
    index = {nm: i for i, nm in enumerate(order)}
    out = []
    for nm in order:
        b = by_name[nm]
        assert b.direction is not None and b.length is not None
        out.append(
            AsfBone(
                name=nm,
                parent=index[parent_of[nm]] if nm in parent_of else -1,
                direction=b.direction,
                length=b.length,
                axis=b.axis,
                axis_order=b.axis_order,
                dof=b.dof,
                line=b.line,
            )
        )
    return tuple(out)


# --- AMC -------------------------------------------------------------------------------


def read_amc(path: str | Path, asf: Asf) -> Amc:
    """Read an AMC take of ``asf``, plain or gzip-compressed."""
    return parse_amc(_read_lines(path), asf, source=str(path))


def _parse_amc_fast(lines: Sequence[str], asf: Asf, source: str) -> Amc | None:
    """The common case in one vectorised pass: every frame lists the same bones in the
    same order, nothing else between them. ``None`` for anything else, which
    :func:`parse_amc` then reads line by line (and reports with its line)."""
    width = {b.name: len(b.dof) for b in asf.bones}
    radians = asf.angle_unit == "rad"
    start = None
    for i, raw in enumerate(lines):
        tok = raw.split()
        if not tok or tok[0][0] == "#":
            continue
        if tok[0][0] == ":":
            kw = tok[0].upper()
            radians = True if kw == ":RADIANS" else False if kw == ":DEGREES" else radians
            continue
        start = i
        break
    if start is None or not lines[start].strip().isdigit():
        return None
    names: list[str] = []
    for raw in lines[start + 1 :]:
        tok = raw.split()
        if not tok:
            continue
        if len(tok) == 1 and tok[0].isdigit():
            break
        if tok[0] not in width or tok[0] in names or len(tok) != width[tok[0]] + 1:
            return None
        names.append(tok[0])
    per_frame = 1 + sum(1 + width[nm] for nm in names)
    tokens = " ".join(lines[start:]).split()
    if len(tokens) % per_frame:
        return None
    table = np.array(tokens, dtype=object).reshape(-1, per_frame)
    value_cols: dict[str, list[int]] = {}
    col = 1
    for nm in names:
        if not (table[:, col] == nm).all():
            return None
        value_cols[nm] = list(range(col + 1, col + 1 + width[nm]))
        col += 1 + width[nm]
    try:
        numbers = table[:, 0].astype(np.int64)
        cols = [c for nm in names for c in value_cols[nm]]
        values = table[:, cols].astype(np.float64) if cols else np.zeros((len(table), 0))
    except ValueError:
        return None
    if (np.diff(numbers) != 1).any() or not np.isfinite(values).all():
        return None
    out: dict[str, F64] = {nm: np.zeros((len(table), w)) for nm, w in width.items()}
    k = 0
    for nm in names:
        out[nm] = np.ascontiguousarray(values[:, k : k + width[nm]])
        k += width[nm]
    return Amc(out, numbers, radians, source)


def parse_amc(lines: Sequence[str], asf: Asf, source: str = "<string>") -> Amc:
    """Parse AMC text split into lines. ``source`` names the file in error messages."""
    fast = _parse_amc_fast(lines, asf, source)
    if fast is not None:
        return fast
    width = {b.name: len(b.dof) for b in asf.bones}
    radians = asf.angle_unit == "rad"
    frames: list[int] = []
    # Per bone: the frame index, the values and the line of every line that gives it.
    at: dict[str, list[int]] = {nm: [] for nm in width}
    vals: dict[str, list[list[float]]] = {nm: [] for nm in width}
    where: dict[str, list[int]] = {nm: [] for nm in width}
    seen: set[str] = set()
    frame = -1
    for n, raw in enumerate(lines, start=1):
        tok = raw.split()
        if not tok:
            continue
        head = tok[0]
        if head[0] == "#":
            continue
        if head[0] == ":":
            kw = head.upper()
            if kw == ":RADIANS":
                radians = True
            elif kw == ":DEGREES":
                radians = False
            elif frames:
                raise AcclaimError(f"{head!r} after the first frame", file=source, line=n)
            continue
        if len(tok) == 1 and head.isdigit():
            number = int(head)
            if frames and number != frames[-1] + 1:
                raise AcclaimError(
                    f"frame {number} follows frame {frames[-1]} (frames must be consecutive)",
                    file=source,
                    line=n,
                )
            frames.append(number)
            frame += 1
            seen = set()
            continue
        if not frames:
            raise AcclaimError(
                f"expected a frame number, found {head!r} (not an AMC file?)",
                file=source,
                line=n,
            )
        w = width.get(head)
        if w is None:
            raise AcclaimError(f"unknown bone {head!r} (not in the ASF)", file=source, line=n)
        if head in seen:
            raise AcclaimError(
                f"bone {head!r} appears twice in frame {frames[-1]}", file=source, line=n
            )
        seen.add(head)
        if len(tok) != w + 1:
            raise AcclaimError(
                f"bone {head!r}: expected {w} value(s), found {len(tok) - 1}", file=source, line=n
            )
        try:
            row = [float(t) for t in tok[1:]]
        except ValueError:
            bad = next(t for t in tok[1:] if not _is_float(t))
            raise AcclaimError(
                f"bone {head!r}: {bad!r} is not a number", file=source, line=n
            ) from None
        at[head].append(frame)
        vals[head].append(row)
        where[head].append(n)
    if not frames:
        raise AcclaimError("no frames (not an AMC file?)", file=source, line=max(1, len(lines)))
    out: dict[str, F64] = {}
    for nm, w in width.items():
        arr = np.zeros((len(frames), w), dtype=np.float64)
        if w and at[nm]:
            given = np.asarray(vals[nm], dtype=np.float64)
            finite = np.isfinite(given).all(axis=1)
            if not finite.all():
                n = where[nm][int(np.argmin(finite))]
                raise AcclaimError(f"bone {nm!r}: non-finite value", file=source, line=n)
            arr[np.asarray(at[nm])] = given
        out[nm] = arr
    return Amc(out, np.asarray(frames, dtype=np.int64), radians, source)


# --- conversion ------------------------------------------------------------------------


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
