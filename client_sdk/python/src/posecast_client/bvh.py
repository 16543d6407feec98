"""A minimal BVH reader (with forward kinematics) and writer.

Reading accepts plain or gzip-compressed text, any channel order, position channels
on any joint and ``End Site`` leaves; one ``ROOT``. Problems raise
:class:`~posecast_client.errors.BvhError` with the file and line.

Writing produces what Blender and MotionBuilder import: one ``ROOT`` with six
channels, three rotation channels on every other joint, degrees, metres by default;
:class:`BvhWriter` writes the motion in parts, as it comes.
"""

from __future__ import annotations

import gzip
import io
import os
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from posecast_client.errors import BvhError
from posecast_client.rotations import euler2mat, fk, mat2euler_zyx, quat2mat

F64 = NDArray[np.float64]
_CHANNELS = {f"{a}{k}" for a in "XYZ" for k in ("position", "rotation")}


@dataclass(frozen=True)
class BvhJoint:
    name: str
    parent: int  # index into Bvh.joints, -1 for the root
    offset: tuple[float, float, float]  # file units
    channels: tuple[str, ...]  # e.g. ("Zrotation", "Xrotation", "Yrotation")
    end_site: tuple[float, float, float] | None = None  # an End Site child, if any


@dataclass(frozen=True)
class Bvh:
    """A parsed file: the hierarchy (parents first) and motion ``(frames, channels)``."""

    joints: tuple[BvhJoint, ...]
    frame_time_s: float
    motion: F64
    source: str = "<string>"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def parents(self) -> tuple[int, ...]:
        return tuple(j.parent for j in self.joints)

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    def fk(self, unit_m: float = 1.0) -> tuple[F64, F64]:
        """World rotations ``(F, J, 3, 3)`` and positions ``(F, J, 3)`` in metres.

        ``unit_m`` is the length of one file unit in metres (0.01 for centimetres).
        """
        n_frames, n_joints = self.n_frames, len(self.joints)
        local = np.broadcast_to(np.eye(3), (n_frames, n_joints, 3, 3)).copy()
        trans = np.broadcast_to([j.offset for j in self.joints], (n_frames, n_joints, 3)).copy()
        col = 0
        for ji, joint in enumerate(self.joints):
            cols = {c: col + k for k, c in enumerate(joint.channels)}
            col += len(joint.channels)
            for axis, name in enumerate(("Xposition", "Yposition", "Zposition")):
                if name in cols:
                    trans[:, ji, axis] += self.motion[:, cols[name]]
            rot = [c for c in joint.channels if c.endswith("rotation")]
            if rot:
                angles = np.deg2rad(self.motion[:, [cols[c] for c in rot]])
                local[:, ji] = euler2mat(angles, "".join(c[0] for c in rot))
        trans *= unit_m
        return fk(local, trans[:, 0], trans, self.parents)


def read_bvh(path: str | Path) -> Bvh:
    """Read a BVH file, plain or gzip-compressed (detected by content)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
        if raw[:2] == b"\x1f\x8b":
            raw = gzip.decompress(raw)
    except (OSError, EOFError) as exc:
        raise BvhError(f"cannot read: {exc}", file=str(p)) from exc
    return parse_bvh(raw.decode("utf-8", errors="replace"), source=str(p))


def parse_bvh(text: str, source: str = "<string>") -> Bvh:
    """Parse BVH text; ``source`` names it in errors."""
    lines = text.splitlines()
    try:
        motion_at = next(i for i, ln in enumerate(lines) if ln.strip() == "MOTION")
    except StopIteration:
        raise BvhError("no MOTION section (not BVH, or truncated)", file=source) from None
    toks = [(t, n) for n, ln in enumerate(lines[:motion_at], 1) for t in ln.split()]
    if not toks or toks[0][0] != "HIERARCHY":
        raise BvhError("not a BVH file (no HIERARCHY)", file=source, line=1)
    joints: list[BvhJoint] = []
    pos = _parse_joint(toks, 1, -1, joints, source)
    if pos != len(toks):
        raise BvhError(f"unexpected {toks[pos][0]!r}", file=source, line=toks[pos][1])
    header = [ln.strip() for ln in lines[motion_at + 1 : motion_at + 3]]
    if (
        len(header) < 2
        or not header[0].startswith("Frames:")
        or not header[1].startswith("Frame Time:")
    ):
        raise BvhError(
            "expected Frames: and Frame Time: after MOTION", file=source, line=motion_at + 2
        )
    try:
        n_frames = int(header[0][7:])
        frame_time = float(header[1][11:])
        values = np.array(" ".join(lines[motion_at + 3 :]).split(), dtype=np.float64)
    except ValueError as exc:
        raise BvhError(f"bad motion section: {exc}", file=source, line=motion_at + 2) from None
    n_channels = sum(len(j.channels) for j in joints)
    if n_frames < 1 or not frame_time > 0:
        raise BvhError("need Frames >= 1 and Frame Time > 0", file=source, line=motion_at + 2)
    if values.size < n_frames * n_channels or not np.isfinite(values).all():
        raise BvhError(
            f"motion has {values.size} finite values, need {n_frames} x {n_channels}",
            file=source,
            line=len(lines),
        )
    motion = values[: n_frames * n_channels].reshape(n_frames, n_channels)
    return Bvh(tuple(joints), frame_time, motion, source)


def _parse_joint(
    toks: list[tuple[str, int]], i: int, parent: int, joints: list[BvhJoint], source: str
) -> int:
    """Parse ``ROOT|JOINT name { ... }`` starting at token ``i``; returns the next index."""

    def expect(k: int, word: str) -> None:
        if k >= len(toks) or toks[k][0] != word:
            found, line = toks[k] if k < len(toks) else ("end of file", toks[-1][1])
            raise BvhError(f"expected {word!r}, found {found!r}", file=source, line=line)

    def floats(k: int, n: int) -> tuple[float, ...]:
        try:
            return tuple(float(t) for t, _ in toks[k : k + n])
        except ValueError:
            raise BvhError("expected a number", file=source, line=toks[k][1]) from None

    expect(i, "JOINT" if parent >= 0 else "ROOT")
    name = toks[i + 1][0] if i + 1 < len(toks) else ""
    expect(i + 2, "{")
    expect(i + 3, "OFFSET")
    x, y, z = floats(i + 4, 3)
    i += 7
    channels: tuple[str, ...] = ()
    if i < len(toks) and toks[i][0] == "CHANNELS":
        n = int(floats(i + 1, 1)[0])
        channels = tuple(t for t, _ in toks[i + 2 : i + 2 + n])
        if len(channels) != n or not set(channels) <= _CHANNELS:
            raise BvhError(f"bad channels {channels}", file=source, line=toks[i][1])
        i += 2 + n
    index = len(joints)
    joints.append(BvhJoint(name, parent, (x, y, z), channels))
    while i < len(toks) and toks[i][0] != "}":
        if toks[i][0] == "JOINT":
            i = _parse_joint(toks, i, index, joints, source)
        elif toks[i][0] == "End":
            expect(i + 1, "Site")
            expect(i + 2, "{")
            expect(i + 3, "OFFSET")
            ex, ey, ez = floats(i + 4, 3)
            expect(i + 7, "}")
            joints[index] = BvhJoint(name, parent, (x, y, z), channels, (ex, ey, ez))
            i += 8
        else:
            raise BvhError(f"unexpected {toks[i][0]!r} in {name!r}", file=source, line=toks[i][1])
    expect(i, "}")
    return i + 1


class BvhWriter:
    """Writes a BVH file (ZYX rotation channels, metres) frame by frame: the hierarchy
    and the motion header on opening, then each batch of frames as it comes, so a long
    motion never has to be in memory whole. ``n_frames`` goes in the header up front,
    and closing checks that so many were written. A path ending ``.gz`` is written
    gzip-compressed (the bytes :func:`gzip.compress` with ``mtime=0`` gives).

    The file is written as ``<path>.part`` beside ``path`` and renamed to ``path`` by
    :meth:`close` once whole, so a failure on the way (:meth:`abandon`, which deletes
    the part, or a frame count other than the header's) leaves no broken file behind
    and a file already at ``path`` (an earlier export) as it was.

    Args:
        names, parents: joints with parents first (``parents[0] == -1``).
        offsets: ``(J, 3)`` rest offsets, metres.
        n_frames: the frames that will be written.
        frame_time_s: seconds per frame.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        names: Sequence[str],
        parents: Sequence[int],
        offsets: ArrayLike,
        n_frames: int,
        frame_time_s: float,
    ) -> None:
        self.n_frames, self.written = n_frames, 0
        self.path = Path(path)
        self.part = self.path.with_name(self.path.name + ".part")  # renamed to path when whole
        self._gzip = zlib.compressobj(9, zlib.DEFLATED, 31) if str(path).endswith(".gz") else None
        self._f: BinaryIO = self.part.open("wb")  # closed by close() or abandon()
        try:
            self.order = self._write_hierarchy(names, parents, offsets)
            self._write(f"MOTION\nFrames: {n_frames}\nFrame Time: {frame_time_s:.8f}\n")
        except BaseException:
            self.abandon()
            raise

    def _write_hierarchy(
        self, names: Sequence[str], parents: Sequence[int], offsets: ArrayLike
    ) -> list[int]:
        """Write HIERARCHY; returns the joints depth first, the order of the columns."""
        off = np.asarray(offsets, dtype=np.float64)
        kids: list[list[int]] = [[] for _ in parents]
        for j, p in enumerate(parents):
            if p >= 0:
                kids[p].append(j)
        out = io.StringIO()
        out.write("HIERARCHY\n")
        order: list[int] = []

        def emit(j: int, depth: int) -> None:
            order.append(j)
            pad = "\t" * depth
            out.write(f"{pad}{'ROOT' if parents[j] < 0 else 'JOINT'} {names[j]}\n{pad}{{\n")
            out.write(f"{pad}\tOFFSET {off[j, 0]:.6f} {off[j, 1]:.6f} {off[j, 2]:.6f}\n")
            pos = "Xposition Yposition Zposition " if parents[j] < 0 else ""
            out.write(f"{pad}\tCHANNELS {6 if pos else 3} {pos}Zrotation Yrotation Xrotation\n")
            for c in kids[j]:
                emit(c, depth + 1)
            if not kids[j]:  # a leaf: a short End Site along its bone, so the bone shows
                tip = off[j] * 0.25 if np.linalg.norm(off[j]) > 0 else np.array([0.0, 0.05, 0.0])
                out.write(f"{pad}\tEnd Site\n{pad}\t{{\n")
                out.write(f"{pad}\t\tOFFSET {tip[0]:.6f} {tip[1]:.6f} {tip[2]:.6f}\n{pad}\t}}\n")
            out.write(f"{pad}}}\n")

        emit(0, 0)
        self._write(out.getvalue())
        return order

    def _write(self, text: str) -> None:
        data = text.encode("utf-8")
        self._f.write(self._gzip.compress(data) if self._gzip is not None else data)

    def write_frames(self, root_pos: ArrayLike, local_quat: ArrayLike) -> None:
        """Append frames: ``root_pos (F, 3)`` root positions and ``local_quat (F, J, 4)``
        xyzw local rotations (the root's is its world rotation)."""
        euler = np.rad2deg(mat2euler_zyx(quat2mat(local_quat)))  # (F, J, 3) as Z, Y, X
        if self.written + euler.shape[0] > self.n_frames:
            raise ValueError(f"more than the {self.n_frames} frames the header says")
        table = np.concatenate(
            [np.asarray(root_pos, dtype=np.float64)] + [euler[:, j] for j in self.order], 1
        )
        out = io.StringIO()
        np.savetxt(out, table, fmt="%.6f")
        self._write(out.getvalue())
        self.written += euler.shape[0]

    def close(self) -> None:
        """Finish the file and rename it to ``path``; a count of frames other than the
        header's is a ValueError (the part is deleted, ``path`` left as it was)."""
        if self._f.closed:
            return
        try:
            if self.written != self.n_frames:
                raise ValueError(f"{self.written} frames written, the header says {self.n_frames}")
            if self._gzip is not None:
                self._f.write(self._gzip.flush())
            self._f.close()
            os.replace(self.part, self.path)
        except BaseException:
            self.abandon()
            raise

    def abandon(self) -> None:
        """Close and delete the unfinished part (after an error on the way); a file
        already at ``path`` stays as it was."""
        self._f.close()
        self.part.unlink(missing_ok=True)

    def __enter__(self) -> BvhWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        if kind is None:
            self.close()
        else:  # an error on the way: the count's error must not hide it
            self.abandon()


def write_bvh(
    path: str | Path,
    *,
    names: Sequence[str],
    parents: Sequence[int],
    offsets: ArrayLike,
    root_pos: ArrayLike,
    local_quat: ArrayLike,
    frame_time_s: float,
) -> None:
    """Write a skeleton and its motion as BVH (ZYX rotation channels, metres); for a
    motion written in parts, :class:`BvhWriter`.

    Args:
        names, parents: joints with parents first (``parents[0] == -1``).
        offsets: ``(J, 3)`` rest offsets, metres.
        root_pos: ``(F, 3)`` root positions; local_quat: ``(F, J, 4)`` xyzw local
            rotations (the root's is its world rotation).
        frame_time_s: seconds per frame.
    """
    n_frames = np.shape(local_quat)[0]
    with BvhWriter(
        path,
        names=names,
        parents=parents,
        offsets=offsets,
        n_frames=n_frames,
        frame_time_s=frame_time_s,
    ) as writer:
        writer.write_frames(root_pos, local_quat)
