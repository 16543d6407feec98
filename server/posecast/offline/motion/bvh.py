"""BVH reading and writing.

Reading accepts plain or gzip-compressed files (detected by content, not by name),
any channel order, position channels on any joint, and ``End Site`` leaves. Every
problem raises :class:`~posecast.errors.BvhError` naming the file and the line.

Writing produces a file Blender and MotionBuilder open: one ``ROOT`` with six
channels, three rotation channels per joint, degrees, lengths in the given unit.
"""

from __future__ import annotations

import gzip
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast.errors import BvhError
from posecast.geometry.rotations import euler2mat, mat2euler, quat2mat
from posecast.offline.motion.gzfile import read_maybe_gzip

_VALID_CHANNELS = {f"{axis}{kind}" for axis in "XYZ" for kind in ("position", "rotation")}


@dataclass(frozen=True)
class BvhJoint:
    """One joint of a BVH hierarchy, in file order (parents before children)."""

    name: str
    parent: int  # index into Bvh.joints, -1 for the root
    offset: tuple[float, float, float]
    channels: tuple[str, ...]
    end_site: tuple[float, float, float] | None  # offset of an End Site child, if any
    line: int  # 1-based line of its ROOT/JOINT keyword

    @property
    def rotation_order(self) -> str:
        """Axis letters of the rotation channels in file order, e.g. ``"ZXY"``."""
        return "".join(c[0] for c in self.channels if c.endswith("rotation"))


@dataclass(frozen=True)
class Bvh:
    """A parsed BVH file: hierarchy plus the raw motion channels ``(frames, channels)``."""

    joints: tuple[BvhJoint, ...]
    frame_time_s: float
    motion: NDArray[np.float64]
    source: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def parents(self) -> tuple[int, ...]:
        return tuple(j.parent for j in self.joints)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time_s

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def offsets(self) -> NDArray[np.float64]:
        """Rest offsets ``(J, 3)`` in file units."""
        return np.array([j.offset for j in self.joints], dtype=np.float64)

    def local_transforms(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per-frame local rotations ``(F, J, 3, 3)`` and translations ``(F, J, 3)``.

        A joint's translation is its offset plus its position channels, if any.
        """
        n_frames, n_joints = self.n_frames, len(self.joints)
        rot = np.broadcast_to(np.eye(3), (n_frames, n_joints, 3, 3)).copy()
        trans = np.broadcast_to(self.offsets(), (n_frames, n_joints, 3)).copy()
        col = 0
        for ji, joint in enumerate(self.joints):
            idx = {c: col + k for k, c in enumerate(joint.channels)}
            col += len(joint.channels)
            for axis_i, axis in enumerate("XYZ"):
                if f"{axis}position" in idx:
                    trans[:, ji, axis_i] += self.motion[:, idx[f"{axis}position"]]
            rot_cols = [idx[c] for c in joint.channels if c.endswith("rotation")]
            if rot_cols:
                angles = np.deg2rad(self.motion[:, rot_cols])
                rot[:, ji] = euler2mat(angles, joint.rotation_order)
        return rot, trans


def read_bvh(path: str | Path) -> Bvh:
    """Read a BVH file, plain or gzip-compressed."""
    p = Path(path)
    raw = read_maybe_gzip(p, BvhError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        try:
            text = raw.decode("latin-1")
        except UnicodeDecodeError as exc:  # pragma: no cover - latin-1 decodes anything
            raise BvhError("not a text file", file=p) from exc
    return parse_bvh(text, source=str(p))


class _Tokens:
    """Whitespace tokens of the hierarchy section, each with its line number."""

    def __init__(self, lines: Sequence[str], source: str) -> None:
        self.items: list[tuple[str, int]] = []
        self.source = source
        self.pos = 0
        self.last_line = len(lines)
        for n, line in enumerate(lines, start=1):
            for tok in line.split():
                self.items.append((tok, n))

    def peek(self) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise BvhError("unexpected end of hierarchy", file=self.source, line=self.last_line)
        return self.items[self.pos]

    def next(self) -> tuple[str, int]:
        tok = self.peek()
        self.pos += 1
        return tok

    def expect(self, word: str) -> int:
        tok, line = self.next()
        if tok != word:
            raise BvhError(f"expected {word!r}, found {tok!r}", file=self.source, line=line)
        return line

    def floats(self, n: int) -> tuple[float, ...]:
        out = []
        for _ in range(n):
            tok, line = self.next()
            try:
                out.append(float(tok))
            except ValueError:
                raise BvhError(
                    f"expected a number, found {tok!r}", file=self.source, line=line
                ) from None
        return tuple(out)


def parse_bvh(text: str, source: str = "<string>") -> Bvh:
    """Parse BVH text. ``source`` names the file in error messages."""
    lines = text.splitlines()
    motion_at = next((i for i, ln in enumerate(lines) if ln.strip() == "MOTION"), None)
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is None or lines[first].strip() != "HIERARCHY":
        raise BvhError(
            "not a BVH file (no HIERARCHY header)",
            file=source,
            line=(first + 1) if first is not None else 1,
        )
    if motion_at is None:
        raise BvhError("no MOTION section (file truncated?)", file=source, line=len(lines))
    toks = _Tokens(lines[:motion_at], source)
    toks.pos = 1  # skip HIERARCHY
    joints: list[BvhJoint] = []
    tok, line = toks.next()
    if tok != "ROOT":
        raise BvhError(f"expected 'ROOT', found {tok!r}", file=source, line=line)
    _parse_joint(toks, joints, parent=-1, keyword_line=line)
    if toks.pos != len(toks.items):
        extra, ln = toks.items[toks.pos]
        raise BvhError(
            f"unexpected {extra!r} after the root joint (only one ROOT is supported)",
            file=source,
            line=ln,
        )
    n_channels = sum(len(j.channels) for j in joints)
    n_frames, frame_time, data_at = _parse_motion_header(lines, motion_at, source)
    motion = _parse_motion_rows(lines, data_at, n_frames, n_channels, source)
    return Bvh(tuple(joints), frame_time, motion, source)


def _parse_joint(toks: _Tokens, joints: list[BvhJoint], parent: int, keyword_line: int) -> None:
    name, _ = toks.next()
    toks.expect("{")
    toks.expect("OFFSET")
    offset = toks.floats(3)
    channels: tuple[str, ...] = ()
    if toks.peek()[0] == "CHANNELS":
        toks.next()
        count_tok, cline = toks.next()
        try:
            count = int(count_tok)
        except ValueError:
            raise BvhError(
                f"bad channel count {count_tok!r}", file=toks.source, line=cline
            ) from None
        chans = []
        for _ in range(count):
            ch, chl = toks.next()
            if ch not in _VALID_CHANNELS:
                raise BvhError(f"unknown channel {ch!r}", file=toks.source, line=chl)
            chans.append(ch)
        channels = tuple(chans)
    if any(name == j.name for j in joints):
        raise BvhError(f"duplicate joint name {name!r}", file=toks.source, line=keyword_line)
    index = len(joints)
    joints.append(BvhJoint(name, parent, offset, channels, None, keyword_line))  # type: ignore[arg-type]
    end_site: tuple[float, ...] | None = None
    while True:
        tok, line = toks.next()
        if tok == "}":
            break
        if tok == "JOINT":
            _parse_joint(toks, joints, parent=index, keyword_line=line)
        elif tok == "End":
            toks.expect("Site")
            toks.expect("{")
            toks.expect("OFFSET")
            end_site = toks.floats(3)
            toks.expect("}")
        else:
            raise BvhError(f"unexpected {tok!r} in joint {name!r}", file=toks.source, line=line)
    if end_site is not None:
        j = joints[index]
        joints[index] = BvhJoint(j.name, j.parent, j.offset, j.channels, end_site, j.line)  # type: ignore[arg-type]


def _parse_motion_header(
    lines: Sequence[str], motion_at: int, source: str
) -> tuple[int, float, int]:
    i = motion_at + 1
    values: dict[str, tuple[str, int]] = {}  # key -> (value text, 1-based line)
    for key in ("Frames:", "Frame Time:"):
        while i < len(lines) and not lines[i].strip():
            i += 1
        if i >= len(lines) or not lines[i].strip().startswith(key):
            raise BvhError(
                f"expected {key!r} after MOTION", file=source, line=min(i + 1, len(lines))
            )
        values[key] = (lines[i].strip()[len(key) :].strip(), i + 1)
        i += 1
    frames_text, frames_line = values["Frames:"]
    time_text, time_line = values["Frame Time:"]
    try:
        n_frames = int(frames_text)
    except ValueError:
        raise BvhError(f"bad Frames value {frames_text!r}", file=source, line=frames_line) from None
    if n_frames < 0:
        raise BvhError("Frames must be >= 0", file=source, line=frames_line)
    try:
        frame_time = float(time_text)
    except ValueError:
        raise BvhError(f"bad Frame Time value {time_text!r}", file=source, line=time_line) from None
    if not (frame_time > 0.0 and np.isfinite(frame_time)):
        raise BvhError("Frame Time must be > 0", file=source, line=time_line)
    return n_frames, frame_time, i


def _parse_motion_rows(
    lines: Sequence[str], start: int, n_frames: int, n_channels: int, source: str
) -> NDArray[np.float64]:
    rows = [(n, ln) for n, ln in enumerate(lines[start:], start=start + 1) if ln.strip()]
    if len(rows) < n_frames:
        raise BvhError(
            f"truncated: header says {n_frames} frames, found {len(rows)}",
            file=source,
            line=len(lines),
        )
    rows = rows[:n_frames]
    try:
        flat = np.array(" ".join(ln for _, ln in rows).split(), dtype=np.float64)
    except ValueError:
        flat = np.empty(0)
    if flat.size == n_frames * n_channels:
        motion = flat.reshape(n_frames, n_channels)
        if np.all(np.isfinite(motion)):
            return motion
    # Something is wrong: find the first offending line for the message.
    for n, ln in rows:
        parts = ln.split()
        if len(parts) != n_channels:
            raise BvhError(f"expected {n_channels} values, found {len(parts)}", file=source, line=n)
        try:
            vals = [float(v) for v in parts]
        except ValueError:
            raise BvhError("non-numeric motion value", file=source, line=n) from None
        if not all(np.isfinite(vals)):
            raise BvhError("non-finite motion value", file=source, line=n)
    raise BvhError("malformed motion data", file=source)  # pragma: no cover


def write_bvh(
    path: str | Path,
    *,
    names: Sequence[str],
    parents: Sequence[int],
    offsets: ArrayLike,
    root_pos: ArrayLike,
    local_quat: ArrayLike,
    frame_time_s: float,
    end_sites: dict[int, ArrayLike] | None = None,
    order: str = "ZYX",
    scale: float = 1.0,
) -> None:
    """Write a skeleton and its motion as BVH.

    Args:
        names, parents: joints in topological order, ``parents[0] == -1``.
        offsets: ``(J, 3)`` rest offsets (metres; multiplied by ``scale`` on output).
        root_pos: ``(F, 3)`` root positions; local_quat: ``(F, J, 4)`` xyzw.
        end_sites: joint index -> End Site offset for leaves (default: a short stub
            along the joint's own offset direction, so every leaf has a visible bone).
        order: rotation channel order written for every joint.
        scale: output length unit per metre (100 writes centimetres).
    """
    off = np.asarray(offsets, dtype=np.float64) * scale
    rp = np.asarray(root_pos, dtype=np.float64) * scale
    q = np.asarray(local_quat, dtype=np.float64)
    n_frames, n_joints = q.shape[0], q.shape[1]
    euler = np.rad2deg(mat2euler(quat2mat(q), order))  # (F, J, 3)
    children: dict[int, list[int]] = {i: [] for i in range(n_joints)}
    for i, p in enumerate(parents):
        if p >= 0:
            children[p].append(i)
    ends = {k: np.asarray(v, dtype=np.float64) * scale for k, v in (end_sites or {}).items()}
    out = io.StringIO()
    out.write("HIERARCHY\n")
    rot_channels = " ".join(f"{a}rotation" for a in order)

    def emit(j: int, depth: int) -> None:
        pad = "\t" * depth
        kind = "ROOT" if parents[j] < 0 else "JOINT"
        out.write(f"{pad}{kind} {names[j]}\n{pad}{{\n")
        o = off[j]
        out.write(f"{pad}\tOFFSET {o[0]:.6f} {o[1]:.6f} {o[2]:.6f}\n")
        if parents[j] < 0:
            out.write(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition {rot_channels}\n")
        else:
            out.write(f"{pad}\tCHANNELS 3 {rot_channels}\n")
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            e = ends.get(j)
            if e is None:
                e = (
                    off[j] * 0.25
                    if np.linalg.norm(off[j]) > 0
                    else np.array([0.0, 0.05 * scale, 0])
                )
            out.write(
                f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET {e[0]:.6f} {e[1]:.6f} {e[2]:.6f}\n"
            )
            out.write(f"{pad}\t}}\n")
        out.write(f"{pad}}}\n")

    emit(0, 0)
    out.write(f"MOTION\nFrames: {n_frames}\nFrame Time: {frame_time_s:.8f}\n")
    # Channel order in the file is depth-first, the same as the emit order.
    dfs: list[int] = []

    def walk(j: int) -> None:
        dfs.append(j)
        for c in children[j]:
            walk(c)

    walk(0)
    cols = [rp] + [euler[:, j, :] for j in dfs]
    table = np.concatenate(cols, axis=1)
    np.savetxt(out, table, fmt="%.6f")
    data = out.getvalue().encode("utf-8")
    target = Path(path)
    if target.suffix == ".gz":
        data = gzip.compress(data, mtime=0)
    target.write_bytes(data)
