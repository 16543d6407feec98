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

A truncated last record (the recorder was killed) is ignored on reading; any other
bytes that are not a record make the file corrupt.

**Reading.** :func:`open_recording` reads a file record by record (memory stays flat
however long the recording: hours at 60 Hz); :func:`read_recording` reads all of it
into a :class:`Recording`. :func:`export_bvh` takes either.

**BVH export** writes each player's poses on the canonical 19-joint skeleton at the
room's pose rate, one frame per tick (``pose.t``; a tick without a pose for that
player repeats the previous frame). Where a player's ``pose.t`` jumps by more than
``MAX_GAP_S`` (10 s) from one pose to the next in order of arrival (the recorder
rejoined a server with another clock, or the player was away that long), the poses
after the jump follow on the next tick. Bone lengths are the player's median measured
lengths along the reference directions. Rotations are the server's when poses carry
``rot``; positions-only poses are turned into rotations by aligning bones: a joint
with several children takes the least-squares rotation of its child bones (Kabsch),
a joint with one child the smallest turn of its parent's frame onto that bone, a
leaf its parent's rotation.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Generator, Iterator
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
MAX_GAP_S = 10.0  # a longer jump of a player's pose.t is another clock, not a pause
DEFAULT_RATE_HZ = 60.0  # the pose rate of a recording without a welcome


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
        return DEFAULT_RATE_HZ if w is None else w.rate_hz


class RecordingReader:
    """A recording read one record at a time (see :func:`open_recording`).

    ``header`` is read on opening; iterating gives each ``(t_s, message)`` (decoded)
    as the file is read, once. Close it (or use ``with``) when done.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f: BinaryIO = self.path.open("rb")
        try:
            with _corrupt_is_recording_error(self.path):
                self._items = _unpack(self._f)
                header = next(self._items, None)
                if not isinstance(header, dict) or header.get("format") != FORMAT:
                    raise RecordingError(f"{path}: not a posecast recording")
                if header.get("version") != VERSION:
                    raise RecordingError(
                        f"{path}: recording version {header.get('version')} is not {VERSION}"
                    )
        except BaseException:
            self._f.close()
            raise
        self.header: dict[str, Any] = header
        self._records = self._read()

    def _read(self) -> Generator[tuple[float, Message], None, None]:
        with _corrupt_is_recording_error(self.path):
            for item in self._items:
                t, data = item
                yield float(t), decode(data)

    def __iter__(self) -> Iterator[tuple[float, Message]]:
        return self._records

    def close(self) -> None:
        self._records.close()
        self._f.close()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_recording(path: str | Path) -> RecordingReader:
    """Open a recording to read it record by record, in memory that does not grow with
    its length::

        with open_recording("lobby.pcrec") as rec:
            for t_s, message in rec:
                ...

    A file that is not a recording (or of another version):
    :class:`~posecast_client.errors.RecordingError` at once; a corrupt record: the same
    error when the reading reaches it (a record cut short at the end is no error)."""
    return RecordingReader(path)


def read_recording(path: str | Path) -> Recording:
    """Read a whole recording (messages decoded) into memory; for a long one,
    :func:`open_recording` reads it record by record. A file that is not one, or is
    corrupt: :class:`~posecast_client.errors.RecordingError`."""
    with open_recording(path) as reader:
        return Recording(reader.header, list(reader))


@contextlib.contextmanager
def _corrupt_is_recording_error(path: Path) -> Iterator[None]:
    """What msgpack and the decoder raise about the file's bytes, as a RecordingError."""
    try:
        yield
    except RecordingError:
        raise
    except (msgpack.UnpackException, ValueError, TypeError, PosecastClientError) as exc:
        raise RecordingError(f"{path}: a corrupt posecast recording ({exc!r})") from exc


MAX_RECORD_BYTES = 1 << 20  # what the reader buffers: no message the recorder writes is near


def _unpack(f: BinaryIO) -> Iterator[Any]:
    """The file's msgpack values. Bytes left over at the end are ignored only when they
    can be a record cut short; anything else undecodable is a corrupt file."""
    unpacker = msgpack.Unpacker(f, raw=False, max_buffer_size=MAX_RECORD_BYTES)
    end = 0
    for value in unpacker:  # raises on a byte no value starts with, ends on a cut one
        yield value
        end = unpacker.tell()
    f.seek(end)
    tail = f.read(MAX_RECORD_BYTES + 16)
    if end and tail and not _cut_record(tail):  # (no header at all: not a recording)
        raise RecordingError(f"{f.name}: a corrupt posecast recording (no record at byte {end})")


def _cut_record(tail: bytes) -> bool:
    """Whether ``tail`` can be the start of a ``[t_s, data]`` record (fixarray 2,
    float64, bin 8/16/32 of at most MAX_RECORD_BYTES) that the end of the file cut."""
    if not b"\x92\xcb".startswith(tail[:2]):
        return False
    if len(tail) <= 10:
        return True  # cut in the time
    width = {0xC4: 1, 0xC5: 2, 0xC6: 4}.get(tail[10])
    if width is None:
        return False
    size = int.from_bytes(tail[11 : 11 + width], "big")
    return len(tail) < 11 + width or len(tail) - 11 - width < size <= MAX_RECORD_BYTES


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
    stretches: list[list[Pose]] = []  # split where pose.t jumps (in order of arrival)
    for q in poses:
        if stretches and abs(q.t - stretches[-1][-1].t) <= MAX_GAP_S:
            stretches[-1].append(q)
        else:
            stretches.append([q])
    ordered: list[Pose] = []
    ticks: list[int] = []
    for stretch in stretches:  # each on the tick after the last one's end
        kept = sorted({q.t: q for q in stretch}.values(), key=lambda q: q.t)  # one per tick
        start = ticks[-1] + 1 if ticks else 0
        ordered += kept
        ticks += [start + round((q.t - kept[0].t) * rate_hz) for q in kept]
    n = ticks[-1] + 1
    idx = np.full(n, -1)
    np.maximum.at(idx, ticks, np.arange(len(ticks)))  # of two poses on one tick, the later
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


def _poses_and_rate(recording: Recording | RecordingReader) -> tuple[dict[str, list[Pose]], float]:
    """Each player's poses and the room's pose rate, as :class:`Recording` gives them;
    of a reader, in one pass that keeps the poses only."""
    if isinstance(recording, Recording):
        return recording.poses(), recording.rate_hz
    poses: dict[str, list[Pose]] = {}
    rate_hz: float | None = None
    for _, m in recording:
        if isinstance(m, Pose):
            poses.setdefault(m.player, []).append(m)
        elif rate_hz is None and isinstance(m, Welcome):
            rate_hz = m.rate_hz
    return poses, DEFAULT_RATE_HZ if rate_hz is None else rate_hz


def export_bvh(recording: Recording | RecordingReader, out_dir: str | Path) -> dict[str, Path]:
    """Write ``<player>.bvh`` for every player in ``recording``; returns their paths.
    A reader (:func:`open_recording`) is read to its end, keeping only the poses.

    ``:`` in an id becomes ``_`` (Windows refuses it in file names). Two players whose
    names would then be the same, or differ only in case (a case-insensitive file
    system), get ``~2``, ``~3``, ... on the later one in id order (``~`` is in no id):
    the returned paths say whose file is whose."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    taken: set[str] = set()
    players, rate_hz = _poses_and_rate(recording)
    for player, poses in sorted(players.items()):
        stem = base = player.replace(":", "_")
        k = 1
        while stem.lower() in taken:
            k += 1
            stem = f"{base}~{k}"
        taken.add(stem.lower())
        path = out / (stem + ".bvh")
        poses2bvh(poses, path, rate_hz)
        paths[player] = path
    return paths
