"""Acclaim ASF skeletons: :func:`read_asf` and :func:`parse_asf` (the convention is
in :mod:`posecast.offline.motion.acclaim`'s docstring)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from posecast.errors import AcclaimError
from posecast.offline.motion.acclaim_text import floats, read_lines

INCH_M = 0.0254
ROOT = "root"
_ROT_DOFS = ("rx", "ry", "rz")
_ROOT_CHANNELS = ("TX", "TY", "TZ", "RX", "RY", "RZ")


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


def _order(text: str, source: str, line: int) -> str:
    order = text.upper()
    if len(order) != 3 or set(order) != set("XYZ"):
        raise AcclaimError(f"bad axis order {text!r} (want e.g. XYZ)", file=source, line=line)
    return order


def read_asf(path: str | Path) -> Asf:
    """Read an ASF (or ``.asx``) skeleton, plain or gzip-compressed."""
    return parse_asf(read_lines(path), source=str(path))


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
                position = tuple(floats(tok[1:], 3, "root position", source, n))  # type: ignore[assignment]
            elif low == "orientation":
                orientation = tuple(floats(tok[1:], 3, "root orientation", source, n))  # type: ignore[assignment]
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
        (length_unit,) = floats(tok[1:], 1, "units length", source, n)
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
        d = floats(tok[1:], 3, "direction", source, n)
        norm = math.sqrt(sum(v * v for v in d))
        bone.direction = (
            (d[0] / norm, d[1] / norm, d[2] / norm) if norm > 1e-12 else (0.0, 0.0, 0.0)
        )
    elif key == "length":
        (bone.length,) = floats(tok[1:], 1, "length", source, n)
        if bone.length < 0:
            raise AcclaimError("length must be >= 0", file=source, line=n)
    elif key == "axis":
        if len(tok) != 5:
            raise AcclaimError(
                "axis: expected three angles and an order, e.g. 'axis 0 0 20 XYZ'",
                file=source,
                line=n,
            )
        bone.axis = tuple(floats(tok[1:4], 3, "axis", source, n))  # type: ignore[assignment]
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
