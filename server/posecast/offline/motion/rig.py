"""Declarative rig maps: how a source BVH skeleton maps onto the canonical joints.

A rig is a JSON file (see ``posecast/offline/motion/rigs/*.json``)::

    {
      "name": "cmu_daz",
      "unit_m": 0.01,                  # metres per file length unit
      "first_frame_is_tpose": true,    # drop frame 1 (a synthetic T-pose)
      "align_floor": true,             # optional, default true
      "joints": {"PELVIS": "hip", ..., "LEFT_TOE": "lFoot.end"}
    }

Every canonical joint names the source joint that sits where it sits. A name ending
in ``.end`` means that joint's ``End Site``. Source joints left out of the map (the
CMU ``LowerBack``, collars, fingers) are skipped: their rotations are composed into
the mapped joints by retargeting in world space. Adding a rig is adding a file;
``posecast data prepare --rigs DIR`` reads more from a directory.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from posecast.errors import RigError
from posecast.offline.motion.bvh import Bvh
from posecast.skeleton import Joint

END_SUFFIX = ".end"


@dataclass(frozen=True)
class SourceRef:
    """A source joint, or the End Site of one."""

    joint: str
    end_site: bool = False

    @classmethod
    def parse(cls, text: str) -> SourceRef:
        if text.endswith(END_SUFFIX):
            return cls(text[: -len(END_SUFFIX)], True)
        return cls(text, False)


@dataclass(frozen=True)
class Rig:
    name: str
    unit_m: float
    first_frame_is_tpose: bool
    align_floor: bool
    joints: dict[Joint, SourceRef]
    description: str = ""

    def missing_joints(self, bvh: Bvh) -> list[str]:
        """Mapped source joints (or End Sites) that ``bvh`` lacks."""
        names = {j.name: j for j in bvh.joints}
        missing = []
        for ref in self.joints.values():
            j = names.get(ref.joint)
            if j is None:
                missing.append(ref.joint)
            elif ref.end_site and j.end_site is None:
                missing.append(ref.joint + END_SUFFIX)
        return missing


def rig_from_dict(data: dict[str, object], origin: str) -> Rig:
    """Validate and build a :class:`Rig` from parsed JSON."""
    try:
        name = str(data["name"])
        unit = float(data["unit_m"])  # type: ignore[arg-type]
        mapping = data["joints"]
    except (KeyError, TypeError, ValueError) as exc:
        raise RigError(f"rig file lacks a valid field: {exc}", file=origin) from exc
    if not isinstance(mapping, dict):
        raise RigError("'joints' must be an object", file=origin)
    if not unit > 0:
        raise RigError("'unit_m' must be positive", file=origin)
    unknown = [k for k in mapping if k not in Joint.__members__]
    if unknown:
        raise RigError(f"unknown canonical joints {unknown}", file=origin)
    absent = [j.name for j in Joint if j.name not in mapping]
    if absent:
        raise RigError("rig must map every canonical joint", file=origin, missing_joints=absent)
    joints = {Joint[k]: SourceRef.parse(str(v)) for k, v in mapping.items()}
    return Rig(
        name=name,
        unit_m=unit,
        first_frame_is_tpose=bool(data.get("first_frame_is_tpose", False)),
        align_floor=bool(data.get("align_floor", True)),
        joints=joints,
        description=str(data.get("description", "")),
    )


def load_rig_file(path: str | Path) -> Rig:
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise RigError(f"cannot read rig file: {exc}", file=p) from exc
    if not isinstance(data, dict):
        raise RigError("rig file must hold a JSON object", file=p)
    return rig_from_dict(data, str(p))


def builtin_rigs() -> list[Rig]:
    """The rigs shipped in ``posecast/offline/motion/rigs``."""
    folder = resources.files("posecast.offline.motion") / "rigs"
    rigs = []
    for item in sorted(folder.iterdir(), key=lambda t: t.name):
        if item.name.endswith(".json"):
            data = json.loads(item.read_text(encoding="utf-8"))
            rigs.append(rig_from_dict(data, f"posecast/offline/motion/rigs/{item.name}"))
    return rigs


def load_rigs(extra_dirs: Iterable[str | Path] = ()) -> list[Rig]:
    """Built-in rigs plus every ``*.json`` in ``extra_dirs`` (later names win)."""
    by_name = {r.name: r for r in builtin_rigs()}
    for d in extra_dirs:
        for f in sorted(Path(d).glob("*.json")):
            rig = load_rig_file(f)
            by_name[rig.name] = rig
    return list(by_name.values())


def detect_rig(bvh: Bvh, rigs: Sequence[Rig], name: str | None = None) -> Rig:
    """The rig ``name``, or the first rig whose joints ``bvh`` has all of."""
    if name is not None:
        chosen = [r for r in rigs if r.name == name]
        if not chosen:
            raise RigError(
                f"unknown rig {name!r}; known: {[r.name for r in rigs]}", file=bvh.source
            )
        missing = chosen[0].missing_joints(bvh)
        if missing:
            raise RigError(
                f"file does not fit rig {name!r}", file=bvh.source, missing_joints=missing
            )
        return chosen[0]
    best: tuple[int, Rig] | None = None
    for rig in rigs:
        missing = rig.missing_joints(bvh)
        if not missing:
            return rig
        if best is None or len(missing) < best[0]:
            best = (len(missing), rig)
    if best is None:
        raise RigError("no rigs are declared", file=bvh.source)
    closest = best[1]
    raise RigError(
        f"skeleton matches no known rig; closest is {closest.name!r}",
        file=bvh.source,
        missing_joints=closest.missing_joints(bvh),
    )
