"""Room recordings (a msgpack stream) and their export to BVH, one file per player.

**File format** (``.pcrec``): a concatenation of msgpack values, nothing else:

1. A header map: ``{"format": "posecast-recording", "version": 1, "url": str,
   "room": str, "started_unix": float}`` (``started_unix``: wall-clock start).
2. Then one array per message received: ``[t_s, data]``, where ``t_s`` (float64) is
   the receive time in seconds since the recording started (the recorder's
   monotonic clock) and ``data`` (bin) is the wire message in canonical v1 bytes,
   which is what a conforming server sends; decode it with
   :func:`posecast_client.codec.decode`. Recorded types: ``welcome`` (again after each
   rejoin), ``pose``, ``presence`` and non-fatal ``error``.

A truncated last record (the recorder was killed) is ignored on reading.

**BVH export** writes each player's poses on the canonical 19-joint skeleton at the
room's pose rate, one frame per tick (``pose.t``; a tick without a pose for that
player repeats the previous frame). Bone lengths are the player's median measured
lengths along the reference directions. Rotations are the server's when poses carry
``rot``; positions-only poses are turned into rotations by aligning bones: a joint
with several children takes the least-squares rotation of its child bones (Kabsch),
a joint with one child the smallest turn of its parent's frame onto that bone, a
leaf its parent's rotation.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import msgpack
import numpy as np

from posecast_client.bvh import write_bvh
from posecast_client.codec import decode, encode
from posecast_client.errors import PosecastClientError, RecordingError
from posecast_client.protocol import Message, Pose, Welcome
from posecast_client.rotations import F64, kabsch, mat2quat, quat2mat, vecs2mat
from posecast_client.skeleton import JOINT_NAMES, PARENTS, children, reference_offsets

FORMAT = "posecast-recording"
VERSION = 1


class RecordingWriter:
    """Appends messages to a recording file; flushes every ``flush_every`` records."""

    def __init__(self, path: str | Path, *, url: str, room: str, flush_every: int = 64) -> None:
        self._f: BinaryIO = Path(path).open("wb")  # noqa: SIM115 - closed by close()
        self._start = time.monotonic()
        self._flush_every, self._pending = flush_every, 0
        self.count = 0
        header = {"format": FORMAT, "version": VERSION, "url": url, "room": room,
                  "started_unix": time.time()}  # fmt: skip
        self._f.write(msgpack.packb(header, use_bin_type=True))

    def write(self, msg: Message, now: float | None = None) -> None:
        """Record ``msg``, received at ``now`` (``time.monotonic()``; default: now)."""
        t = (time.monotonic() if now is None else now) - self._start
        self._f.write(msgpack.packb([t, encode(msg)], use_bin_type=True))
        self.count += 1
        self._pending += 1
        if self._pending >= self._flush_every:
            self._f.flush()
            self._pending = 0

    def close(self) -> None:
        self._f.close()


@dataclass
class Recording:
    header: dict[str, Any]
    messages: list[tuple[float, Message]] = field(default_factory=list)

    def poses(self) -> dict[str, list[Pose]]:
        """Each player's poses, in order of arrival."""
        out: dict[str, list[Pose]] = {}
        for _, m in self.messages:
            if isinstance(m, Pose):
                out.setdefault(m.player, []).append(m)
        return out

    @property
    def rate_hz(self) -> float:
        """The room's pose rate, from the first ``welcome`` (60 without one)."""
        w = next((m for _, m in self.messages if isinstance(m, Welcome)), None)
        return 60.0 if w is None else w.rate_hz


def read_recording(path: str | Path) -> Recording:
    """Read a whole recording (messages decoded). A file that is not one, or is cut
    short or corrupt: :class:`~posecast_client.errors.RecordingError`."""
    with Path(path).open("rb") as f:
        try:
            items = _unpack(f)
            header = next(items, None)
            if not isinstance(header, dict) or header.get("format") != FORMAT:
                raise RecordingError(f"{path}: not a posecast recording")
            if header.get("version") != VERSION:
                raise RecordingError(
                    f"{path}: recording version {header.get('version')} is not {VERSION}"
                )
            rec = Recording(header)
            for item in items:
                t, data = item
                rec.messages.append((float(t), decode(data)))
        except (msgpack.UnpackException, ValueError, TypeError, PosecastClientError) as exc:
            if isinstance(exc, RecordingError):
                raise
            raise RecordingError(f"{path}: a corrupt posecast recording ({exc})") from exc
    return rec


def _unpack(f: BinaryIO) -> Iterator[Any]:
    unpacker = msgpack.Unpacker(f, raw=False, max_buffer_size=1 << 20)
    try:
        yield from unpacker
    except (msgpack.OutOfData, ValueError):
        return  # a truncated tail


def world_rotations(positions: F64) -> F64:
    """World rotations ``(F, 19, 3, 3)`` that point the reference bones along the
    measured ones of ``positions (F, 19, 3)`` (see the module docstring)."""
    off = reference_offsets()
    n = positions.shape[0]
    g = np.empty((n, len(PARENTS), 3, 3))
    for j, p in enumerate(PARENTS):
        kids = children(j)
        base = np.broadcast_to(np.eye(3), (n, 3, 3)) if p < 0 else g[:, p]
        if len(kids) >= 2:
            now = positions[:, kids] - positions[:, j : j + 1]  # (F, K, 3)
            g[:, j] = kabsch(np.broadcast_to(off[list(kids)], now.shape), now)
        elif len(kids) == 1:
            c = kids[0]
            predicted = np.einsum("fab,b->fa", base, off[c])
            g[:, j] = vecs2mat(predicted, positions[:, c] - positions[:, j]) @ base
        else:
            g[:, j] = base
    return g


def poses2bvh(poses: list[Pose], path: str | Path, rate_hz: float = 60.0) -> int:
    """Write one player's poses as a BVH file; returns the number of frames."""
    if not poses:
        raise ValueError("no poses to export")
    ordered = sorted({q.t: q for q in poses}.values(), key=lambda q: q.t)  # one per tick
    t0 = ordered[0].t
    n = round((ordered[-1].t - t0) * rate_hz) + 1
    idx = np.full(n, -1)
    for k, pose in enumerate(ordered):
        idx[min(n - 1, round((pose.t - t0) * rate_hz))] = k
    idx = np.maximum.accumulate(idx)  # a tick without a pose holds the previous one
    pos = np.stack([q.positions for q in ordered])[idx]  # (F, 19, 3)
    rotations = [q.rotations for q in ordered if q.rotations is not None]
    if len(rotations) == len(ordered):
        world = quat2mat(np.stack(rotations)[idx])  # (F, 19, 3, 3)
    else:
        world = world_rotations(pos)
    local = world.copy()
    for j, p in enumerate(PARENTS):
        if p >= 0:
            local[:, j] = np.swapaxes(world[:, p], -1, -2) @ world[:, j]
    ref = reference_offsets()
    lengths = np.ones(len(PARENTS))
    for j, p in enumerate(PARENTS):
        if p >= 0:
            measured = np.median(np.linalg.norm(pos[:, j] - pos[:, p], axis=-1))
            lengths[j] = measured / np.linalg.norm(ref[j])
    write_bvh(
        path,
        names=JOINT_NAMES,
        parents=PARENTS,
        offsets=ref * lengths[:, None],
        root_pos=pos[:, 0],
        local_quat=mat2quat(local),
        frame_time_s=1.0 / rate_hz,
    )
    return n


def export_bvh(recording: Recording, out_dir: str | Path) -> dict[str, Path]:
    """Write ``<player>.bvh`` for every player in ``recording``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for player, poses in sorted(recording.poses().items()):
        path = out / (player.replace(":", "_") + ".bvh")
        poses2bvh(poses, path, recording.rate_hz)
        paths[player] = path
    return paths
