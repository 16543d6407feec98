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
into a :class:`Recording`. :func:`export_bvh` takes either, and reads it twice: first
keeping each pose's time and bone lengths (about 170 bytes a pose), then writing the
frames as their poses come, EXPORT_CHUNK_FRAMES at a time (a pipe, which cannot be
read twice, is copied to a file as the first pass reads it).

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
import itertools
import os
import stat
import tempfile
import time
from array import array
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import msgpack
import numpy as np
from numpy.typing import NDArray

from posecast_client.bvh import BvhWriter
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
    as the file is read, once. Close it (or use ``with``) when done. The path may be
    a pipe (``/dev/stdin``, a process substitution): read once, as a file.

    Attributes:
        records_read: the records iterating has given so far.
        welcome_rate_hz: the rate of the first ``welcome`` iterating has given (None
            before one).
        regular: whether the path is a regular file (one that can be opened again
            and read from the start; a pipe cannot).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f: BinaryIO = self.path.open("rb")
        self.regular = stat.S_ISREG(os.fstat(self._f.fileno()).st_mode)
        self.records_read = 0
        self.welcome_rate_hz: float | None = None
        self._tee: Callable[[float, bytes], object] | None = None  # export_bvh's spool
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
                message = decode(data)
                if self.welcome_rate_hz is None and isinstance(message, Welcome):
                    self.welcome_rate_hz = message.rate_hz
                if self._tee is not None:
                    self._tee(float(t), data)
                self.records_read += 1
                yield float(t), message

    def __iter__(self) -> Iterator[tuple[float, Message]]:
        return self._records

    @property
    def closed(self) -> bool:
        return self._f.closed

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


class _KeepsTail:
    """A stream that cannot seek (a pipe), read through this to keep its last bytes:
    those the unpacker read but did not use (at most its buffer, and a read more)."""

    KEEP = 2 * MAX_RECORD_BYTES + (1 << 16)

    def __init__(self, f: BinaryIO) -> None:
        self._f, self.total = f, 0
        self._chunks: deque[bytes] = deque()
        self._kept = 0

    def read(self, n: int = -1) -> bytes:
        data = self._f.read(n)
        self.total += len(data)
        self._chunks.append(data)
        self._kept += len(data)
        while self._kept - len(self._chunks[0]) >= self.KEEP:
            self._kept -= len(self._chunks.popleft())
        return data

    def after(self, end: int) -> bytes:
        """The bytes after the first ``end`` ones (the stream read to its end)."""
        return b"".join(self._chunks)[max(self._kept - (self.total - end), 0) :]


def _unpack(f: BinaryIO) -> Iterator[Any]:
    """The file's msgpack values. Bytes left over at the end are ignored only when they
    can be a record cut short; anything else undecodable is a corrupt file."""
    src = f if f.seekable() else _KeepsTail(f)
    unpacker = msgpack.Unpacker(src, raw=False, max_buffer_size=MAX_RECORD_BYTES)
    end = 0
    for value in unpacker:  # raises on a byte no value starts with, ends on a cut one
        yield value
        end = unpacker.tell()
    if isinstance(src, _KeepsTail):
        tail = src.after(end)[: MAX_RECORD_BYTES + 16]
    else:
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


EXPORT_CHUNK_FRAMES = 1024  # frames turned into rotations and written at a time


class _Track:
    """What the first pass keeps of one player's poses, in order of arrival: ``pose.t``,
    whether it carries rotations and its bone lengths (about 170 bytes a pose, where a
    decoded pose takes 1.6 kB)."""

    def __init__(self) -> None:
        self.t = array("d")
        self.has_rot = bytearray()
        self.lengths = array("d")  # (poses, 18): joint 1.. to its parent
        self._pending: list[F64] = []

    def add(self, pose: Pose) -> None:
        self.t.append(pose.t)
        self.has_rot.append(pose.rotations is not None)
        self._pending.append(pose.positions)
        if len(self._pending) >= EXPORT_CHUNK_FRAMES:
            self._measure()

    def _measure(self) -> None:
        if self._pending:
            pos = np.stack(self._pending)
            bones = np.linalg.norm(pos[:, _JOINTS] - pos[:, _PARENTS], axis=-1)
            self.lengths.frombytes(np.ascontiguousarray(bones, dtype=np.float64).tobytes())
            self._pending.clear()

    def plan(self, rate_hz: float) -> _Plan:
        """Each frame's pose, whether to use the poses' rotations, and the bone lengths."""
        self._measure()
        if not self.t:
            raise ValueError("no poses to export")
        ordered, frames = _frames(np.frombuffer(self.t, dtype=np.float64), rate_hz)
        use_rot = bool(np.frombuffer(self.has_rot, dtype=bool)[ordered].all())
        measured = np.frombuffer(self.lengths, dtype=np.float64).reshape(-1, len(_JOINTS))
        ref = reference_offsets()
        lengths = np.ones(len(PARENTS))
        for k, j in enumerate(_JOINTS):  # over the frames: a held pose counts each time
            lengths[j] = np.median(measured[frames, k]) / np.linalg.norm(ref[j])
        return _Plan(frames, use_rot, ref * lengths[:, None])


_JOINTS = [j for j, p in enumerate(PARENTS) if p >= 0]
_PARENTS = [PARENTS[j] for j in _JOINTS]


def _frames(t: F64, rate_hz: float) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The poses (by index in order of arrival, of poses at times ``t``) on the export's
    timeline, and for each frame the pose it shows (see the module docstring): split
    where ``t`` jumps by more than MAX_GAP_S, each stretch in order of ``t`` with one
    pose a time (the last to arrive) on the tick after the previous stretch's end."""
    stretch = np.concatenate([[0], np.cumsum(~(np.abs(np.diff(t)) <= MAX_GAP_S))])
    by_t = np.lexsort((t, stretch))  # stable: of poses at one time, the last comes last
    s, ts = stretch[by_t], t[by_t]
    last = np.ones(len(by_t), dtype=bool)
    last[:-1] = (s[1:] != s[:-1]) | (ts[1:] != ts[:-1])
    ordered, s, ts = by_t[last], s[last], ts[last]
    first = np.flatnonzero(np.concatenate([[True], s[1:] != s[:-1]]))  # of each stretch
    sizes = np.diff(np.append(first, len(s)))
    local = np.rint((ts - np.repeat(ts[first], sizes)) * rate_hz)  # ticks in the stretch
    starts = np.concatenate([[0], np.cumsum(local[first + sizes - 1] + 1)[:-1]])
    ticks = (local + np.repeat(starts, sizes)).astype(np.intp)  # one after another
    idx = np.full(ticks[-1] + 1, -1)
    np.maximum.at(idx, ticks, np.arange(len(ticks)))  # of two poses on one tick, the later
    idx = np.maximum.accumulate(idx)  # a tick without a pose holds the previous one
    return ordered, ordered[idx]


@dataclass
class _Plan:
    frames: NDArray[np.intp]  # (F,) for each frame, the pose's index in order of arrival
    use_rot: bool  # every pose on the timeline carries rotations: use them
    offsets: F64  # (19, 3) the player's bones along the reference directions


class _PlayerExport:
    """The second pass for one player: takes its poses in order of arrival and writes
    the frames as soon as their poses are in, EXPORT_CHUNK_FRAMES at a time. A pose
    that came before one shown ahead of it waits (poses within a stretch are put in
    order of ``t``); a pose no frame shows is dropped at once."""

    def __init__(self, path: Path, plan: _Plan, rate_hz: float) -> None:
        self.path, self.plan, self.rate_hz = path, plan, rate_hz
        self.frames = array("q", plan.frames.astype(np.int64).tobytes())
        self.needed = np.zeros(int(plan.frames.max()) + 1, dtype=bool)
        self.needed[plan.frames] = True
        self.next = 0  # the next frame to write
        self.waiting: dict[int, Pose] = {}
        self.chunk: list[Pose] = []
        self.writer: BvhWriter | None = None

    @property
    def done(self) -> bool:
        return self.next == len(self.frames)

    def add(self, arrival: int, pose: Pose) -> None:
        if arrival >= len(self.needed) or not self.needed[arrival]:
            return
        self.waiting[arrival] = pose
        frames = self.frames
        while self.next < len(frames) and frames[self.next] in self.waiting:
            shown = frames[self.next]
            self.chunk.append(self.waiting[shown])
            self.next += 1
            if self.next == len(frames) or frames[self.next] != shown:
                del self.waiting[shown]  # no later frame shows it
            if len(self.chunk) >= EXPORT_CHUNK_FRAMES or self.done:
                self._write()

    def _write(self) -> None:
        if self.writer is None:  # opened at the first frame: few files open at once
            self.writer = BvhWriter(
                self.path,
                names=JOINT_NAMES,
                parents=PARENTS,
                offsets=self.plan.offsets,
                n_frames=len(self.frames),
                frame_time_s=1.0 / self.rate_hz,
            )
        pos = np.stack([q.positions for q in self.chunk])  # (C, 19, 3)
        if self.plan.use_rot:
            world = quat2mat(np.stack([q.rotations for q in self.chunk]))  # type: ignore[misc]
        else:
            world = world_rotations(pos)
        local = world.copy()
        for j, p in enumerate(PARENTS):
            if p >= 0:
                local[:, j] = np.swapaxes(world[:, p], -1, -2) @ world[:, j]
        self.writer.write_frames(pos[:, 0], mat2quat(local))
        self.chunk.clear()
        if self.done:
            self.writer.close()

    def abandon(self) -> None:
        """Close the file unfinished (an error on the way)."""
        if self.writer is not None:
            self.writer.abandon()


def poses2bvh(poses: list[Pose], path: str | Path, rate_hz: float = 60.0) -> int:
    """Write one player's poses as a BVH file; returns the number of frames."""
    track = _Track()
    for q in poses:
        track.add(q)
    export = _PlayerExport(Path(path), track.plan(rate_hz), rate_hz)
    try:
        for a, q in enumerate(poses):
            export.add(a, q)
    except BaseException:
        export.abandon()
        raise
    return len(export.frames)


def _tracks(
    messages: Iterable[tuple[float, Message]],
) -> tuple[dict[str, _Track], float | None, int]:
    """The first pass: each player's track, the rate of the first ``welcome``, and the
    number of records read."""
    tracks: dict[str, _Track] = {}
    rate_hz: float | None = None
    n = 0
    for _, m in messages:
        n += 1
        if isinstance(m, Pose):
            tracks.setdefault(m.player, _Track()).add(m)
        elif rate_hz is None and isinstance(m, Welcome):
            rate_hz = m.rate_hz
    return tracks, rate_hz, n


class _Spool:
    """The records a reader of a pipe gives in the first pass, written to a recording
    file in the export's directory (removed after), for the second pass to read."""

    def __init__(self, out: Path, reader: RecordingReader) -> None:
        fd, name = tempfile.mkstemp(prefix=".posecast-export-", suffix=".pcrec", dir=out)
        self.path, self.reader = Path(name), reader
        self._f = os.fdopen(fd, "wb")
        self._f.write(msgpack.packb(reader.header, use_bin_type=True))
        reader._tee = self._write

    def _write(self, t: float, data: bytes) -> None:
        self._f.write(msgpack.packb([t, data], use_bin_type=True))

    def finish(self) -> None:
        """The first pass is over: stop copying, and close the file."""
        self.reader._tee = None
        self._f.close()

    def remove(self) -> None:
        self.finish()
        self.path.unlink(missing_ok=True)


@contextlib.contextmanager
def _read_again(
    recording: Recording | RecordingReader, path: Path | None, skip: int
) -> Iterator[Iterable[tuple[float, Message]]]:
    """The recording's messages for the second pass: a reader's file (or its spool) is
    opened again and read past the ``skip`` records it had given before the first pass."""
    if isinstance(recording, Recording) or path is None:
        yield recording.messages if isinstance(recording, Recording) else ()
        return
    with open_recording(path) as again:
        yield itertools.islice(again, skip, None)


def export_bvh(recording: Recording | RecordingReader, out_dir: str | Path) -> dict[str, Path]:
    """Write ``<player>.bvh`` for every player in ``recording``; returns their paths.

    Memory stays small however long the recording: a reader (:func:`open_recording`)
    is read to its end keeping only each pose's time and bone lengths (and the room's
    rate), then its file is read once more, writing the frames as their poses come,
    a chunk at a time. A reader of a pipe (``/dev/stdin``, a process substitution),
    which cannot be read again, is copied to a hidden file in ``out_dir`` as it is
    read, and that is read the second time (then removed).

    A reader read in part exports the rest, at the rate of the first ``welcome`` it
    gave before or after (a recording with none at all: 60 Hz). A closed reader, or
    one read to its end (nothing left, though it gave records), is a
    :class:`~posecast_client.errors.RecordingError`: open the recording again.

    ``:`` in an id becomes ``_`` (Windows refuses it in file names). Two players whose
    names would then be the same, or differ only in case (a case-insensitive file
    system), get ``~2``, ``~3``, ... on the later one in id order (``~`` is in no id):
    the returned paths say whose file is whose."""
    reader = recording if isinstance(recording, RecordingReader) else None
    if reader is not None and reader.closed:
        raise RecordingError(
            f"{reader.path}: the reader is closed; export_bvh reads it: pass it open "
            "(inside its 'with'), or open the recording again"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    skip = reader.records_read if reader is not None else 0
    with contextlib.ExitStack() as cleanup:
        spool: _Spool | None = None
        if reader is not None and not reader.regular:
            spool = _Spool(out, reader)
            cleanup.callback(spool.remove)
        first = recording.messages if isinstance(recording, Recording) else recording
        tracks, rate, n = _tracks(first)
        if spool is not None:
            spool.finish()
        if reader is not None:
            if n == 0 and skip > 0:
                raise RecordingError(
                    f"{reader.path}: the reader was read to its end ({skip} records) before "
                    "export_bvh: nothing is left to export; open the recording again"
                )
            rate = reader.welcome_rate_hz  # the first it gave, before the export or in it
        again = None if reader is None else (spool.path if spool is not None else reader.path)
        return _export(recording, out, tracks, rate, again, 0 if spool is not None else skip)


def _export(
    recording: Recording | RecordingReader,
    out: Path,
    tracks: dict[str, _Track],
    rate: float | None,
    again: Path | None,
    skip: int,
) -> dict[str, Path]:
    """The second pass: each player's file, from the recording's messages (``again``:
    a file to open and read past its first ``skip`` records)."""
    rate_hz = DEFAULT_RATE_HZ if rate is None else rate
    paths = {}
    taken: set[str] = set()
    exports: dict[str, _PlayerExport] = {}
    for player in sorted(tracks):
        stem = base = player.replace(":", "_")
        k = 1
        while stem.lower() in taken:
            k += 1
            stem = f"{base}~{k}"
        taken.add(stem.lower())
        paths[player] = out / (stem + ".bvh")
        exports[player] = _PlayerExport(paths[player], tracks.pop(player).plan(rate_hz), rate_hz)
    arrivals = dict.fromkeys(exports, 0)
    try:
        with _read_again(recording, again, skip) as messages:
            for _, m in messages:
                if isinstance(m, Pose) and m.player in exports:
                    exports[m.player].add(arrivals[m.player], m)
                    arrivals[m.player] += 1
        unfinished = sorted(p for p, e in exports.items() if not e.done)
        if unfinished:
            raise RecordingError(
                f"{getattr(recording, 'path', 'the recording')}: changed while it was "
                f"exported (the poses of {', '.join(unfinished)} are not all there again)"
            )
    except BaseException:
        for e in exports.values():
            e.abandon()
        raise
    return paths
