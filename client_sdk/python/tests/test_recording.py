"""Recordings: the file format, truncated tails, and the BVH export."""

from __future__ import annotations

import gc
import itertools
import os
import threading
import tracemalloc
from pathlib import Path

import msgpack
import numpy as np
import pytest

from posecast_client import recording
from posecast_client.bvh import read_bvh
from posecast_client.codec import encode
from posecast_client.errors import RecordingError
from posecast_client.protocol import Limits, Member, Pose, Presence, Welcome
from posecast_client.recording import (
    RecordingWriter,
    export_bvh,
    open_recording,
    poses2bvh,
    read_recording,
    world_rotations,
)
from posecast_client.rotations import fk, mat2quat, quat2mat
from posecast_client.skeleton import PARENTS, reference_offsets
from posecast_client.sources.walk import walk_motion


def walk_poses(seconds: float = 1.0, with_rotations: bool = True) -> list[Pose]:
    root, local = walk_motion(seconds, 60.0, seed=3)
    world, pos = fk(quat2mat(local), root, reference_offsets(), PARENTS)
    rot = mat2quat(world)
    return [
        Pose("p-1", 100 + k, 50.0 + k / 60.0, pos[k], rot[k] if with_rotations else None)
        for k in range(len(pos))
    ]


def write_looped(path: Path, poses: list[Pose], n: int) -> Path:
    """A recording of ``n`` poses of one player at 60 Hz, ``poses`` looped."""
    w = RecordingWriter(path, url="ws://x/", room="r", flush_every=1024)
    for k in range(n):
        p = poses[k % len(poses)]
        w.write(Pose("p-1", k, k / 60.0, p.positions, p.rotations), now=k / 60.0)
    w.close()
    return path


def test_write_then_read(tmp_path: Path) -> None:
    path = tmp_path / "r.pcrec"
    w = RecordingWriter(path, url="ws://x/", room="lobby", flush_every=2)
    welcome = Welcome(1, "rec", "s", "spectator", "lobby", 1.0, 60.0, 10,
                      (Member("p-1", "P"),), Limits())  # fmt: skip
    w.write(welcome)
    w.write(Presence("join", "lobby", "p-1", "P"))
    for p in walk_poses(0.2):
        w.write(p)
    w.close()
    rec = read_recording(path)
    assert rec.header["room"] == "lobby" and rec.header["version"] == 1
    assert len(rec.messages) == 2 + 12 and rec.rate_hz == 60.0
    times = [t for t, _ in rec.messages]
    assert times == sorted(times) and times[0] >= 0.0
    assert len(rec.poses()["p-1"]) == 12
    data = path.read_bytes()
    path.write_bytes(data[:-7])  # killed mid-record: the partial record is ignored
    assert len(read_recording(path).messages) == 13
    (tmp_path / "bad.pcrec").write_bytes(msgpack.packb({"format": "other"}))
    with pytest.raises(ValueError):
        read_recording(tmp_path / "bad.pcrec")


def test_positions_become_rotations_that_reproduce_them() -> None:
    poses = walk_poses(2.0, with_rotations=False)
    pos = np.stack([p.positions for p in poses])
    world = world_rotations(pos)
    local = world.copy()
    for j, p in enumerate(PARENTS):
        if p >= 0:
            local[:, j] = np.swapaxes(world[:, p], -1, -2) @ world[:, j]
    _, again = fk(local, pos[:, 0], reference_offsets(), PARENTS)
    np.testing.assert_allclose(again, pos, atol=1e-9)


@pytest.mark.parametrize("with_rotations", [True, False])
def test_export_fills_gaps_on_the_tick_timeline(tmp_path: Path, with_rotations: bool) -> None:
    poses = walk_poses(1.0, with_rotations)
    kept = poses[:20] + poses[30:]  # the player went stale for 10 ticks
    n = poses2bvh(kept, tmp_path / "p.bvh", 60.0)
    assert n == len(poses)
    _, fk_pos = read_bvh(tmp_path / "p.bvh").fk()
    want = np.stack([p.positions for p in poses])
    held = want.copy()
    held[20:30] = want[19]  # a gap holds the last pose
    np.testing.assert_allclose(fk_pos, held, atol=2e-5)


def test_export_writes_one_file_per_player(tmp_path: Path) -> None:
    path = tmp_path / "r.pcrec"
    w = RecordingWriter(path, url="ws://x/", room="r")
    for p in walk_poses(0.5):
        w.write(p)
        w.write(Pose("a:b", p.seq, p.t, p.positions + 1.0, p.rotations))
    w.close()
    paths = export_bvh(read_recording(path), tmp_path / "out")
    assert sorted(paths) == ["a:b", "p-1"] and paths["a:b"].name == "a_b.bvh"
    assert all(read_bvh(p).n_frames == 30 for p in paths.values())
    with open_recording(path) as reader:  # read record by record: the same files
        streamed = export_bvh(reader, tmp_path / "streamed")
    for player, p in paths.items():
        assert streamed[player].read_bytes() == p.read_bytes()


def test_players_whose_file_names_would_clash_each_get_a_file(tmp_path: Path) -> None:
    """``a:b`` and ``a_b`` both make ``a_b``, and ``A_B`` is the same file on a
    case-insensitive file system: each player still gets a file of its own."""
    path = tmp_path / "r.pcrec"
    w = RecordingWriter(path, url="ws://x/", room="r")
    players = ("a:b", "a_b", "A_B")
    for p in walk_poses(0.2):
        for k, player in enumerate(players):
            w.write(Pose(player, p.seq, p.t, p.positions + k, p.rotations))
    w.close()
    paths = export_bvh(read_recording(path), tmp_path / "out")
    names = {player: paths[player].name for player in players}
    assert names == {"A_B": "A_B.bvh", "a:b": "a_b~2.bvh", "a_b": "a_b~3.bvh"}
    motions = [read_bvh(paths[player]).motion for player in players]
    assert all(not np.array_equal(a, b) for a, b in itertools.combinations(motions, 2))


def test_bytes_that_are_no_record_are_corrupt_not_a_cut_tail(tmp_path: Path) -> None:
    path = tmp_path / "r.pcrec"
    w = RecordingWriter(path, url="ws://x/", room="lobby")
    for k in range(4):
        w.write(Presence("join", "lobby", f"p-{k}", "P"))
    w.close()
    data = path.read_bytes()
    record = len(msgpack.packb([0.5, encode(Presence("join", "lobby", "p-3", "P"))]))
    middle = len(data) - 2 * record  # between the second and the third record
    for junk in (b"\xc1", b"\xc6\x7f\xff\xff\xff", b"\x00"):  # reserved byte, 2 GB bin, an int
        path.write_bytes(data[:middle] + junk + data[middle:])
        with pytest.raises(RecordingError, match="corrupt"):
            read_recording(path)
        got = []  # read record by record: the records before the junk, then the error
        with open_recording(path) as reader, pytest.raises(RecordingError, match="corrupt"):
            for _, m in reader:
                got.append(m)
        assert [m.player for m in got] == ["p-0", "p-1"]
    header = len(data) - 4 * record
    for cut in range(header, len(data) + 1):  # a cut anywhere after the header is a tail
        path.write_bytes(data[:cut])
        assert len(read_recording(path).messages) == (cut - header) // record
        with open_recording(path) as reader:
            assert sum(1 for _ in reader) == (cut - header) // record


def test_export_follows_on_where_the_server_clock_jumps(tmp_path: Path) -> None:
    before = walk_poses(0.5)
    # The recorder rejoined a node on another host: another clock, far ahead (without
    # the split, the export asks for 6e12 frames, and fails at once).
    after = [Pose(p.player, p.seq + 30, p.t + 1e11, p.positions + 1.0, p.rotations)
             for p in before]  # fmt: skip
    n = poses2bvh(before + after, tmp_path / "p.bvh", 60.0)
    assert n == 60
    _, fk_pos = read_bvh(tmp_path / "p.bvh").fk()
    want = np.stack([p.positions for p in before + after])
    np.testing.assert_allclose(fk_pos, want, atol=2e-5)


def test_a_recording_is_read_record_by_record_in_memory_that_does_not_grow(
    tmp_path: Path,
) -> None:
    """A recording of hours at 60 Hz must not be decoded into memory whole: reading
    four times the records takes no more memory (read whole, it takes 1.6 kB a pose)."""
    poses = walk_poses(1.0)

    def peak(n: int) -> int:
        path = write_looped(tmp_path / f"{n}.pcrec", poses, n)
        tracemalloc.start()
        try:
            with open_recording(path) as reader:
                assert reader.header["room"] == "r"
                assert sum(isinstance(m, Pose) for _, m in reader) == n
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    small, large = peak(500), peak(2000)
    assert large - small < 100_000, (small, large)  # read whole: 2.4 MB more


def test_a_file_that_is_no_recording_is_refused_on_opening(tmp_path: Path) -> None:
    path = tmp_path / "x.pcrec"
    for data, why in [
        (msgpack.packb({"format": "other"}), "not a posecast recording"),
        (msgpack.packb({"format": "posecast-recording", "version": 9}), "version 9 is not 1"),
        (b"", "not a posecast recording"),
        (b"\xc1", "corrupt"),
    ]:
        path.write_bytes(data)
        with pytest.raises(RecordingError, match=why):
            open_recording(path)  # (its file closed: -W error would see it left open)


def _awkward_poses() -> list[Pose]:
    """Poses as a recording can hold them: out of order within a stretch, two at one
    time (the later wins) and two on one tick, gaps, a jump to another clock and back,
    some without rotations."""
    poses = walk_poses(5.0)
    out = [*poses[:40], *poses[50:120]]
    for k in range(0, len(out) - 4, 9):  # out of order
        out[k], out[k + 3] = out[k + 3], out[k]
    p = poses[130]
    out += [p, Pose(p.player, p.seq, p.t, p.positions + 0.01, p.rotations)]  # one time
    out += [Pose(p.player, p.seq, p.t + 0.004, p.positions + 0.02, p.rotations)]  # one tick
    out += [Pose(q.player, q.seq, q.t + 1e6, q.positions + 1.0, q.rotations) for q in poses[:50]]
    out += poses[140:200]
    return out


@pytest.mark.parametrize("with_rotations", [True, False])
def test_the_export_written_in_chunks_is_the_export_written_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, with_rotations: bool
) -> None:
    """The export converts and writes EXPORT_CHUNK_FRAMES frames at a time, holding a
    pose that came early until its frame: the file is the same for any chunk."""
    poses = _awkward_poses()
    if not with_rotations:
        poses[7] = Pose(poses[7].player, poses[7].seq, poses[7].t, poses[7].positions)
    monkeypatch.setattr(recording, "EXPORT_CHUNK_FRAMES", 1 << 30)  # one chunk: all at once
    n = poses2bvh(poses, tmp_path / "whole.bvh", 60.0)
    whole = (tmp_path / "whole.bvh").read_bytes()
    assert n == 131 + 50 + 60  # ticks 0-130 (gaps held), then each stretch after the last
    for chunk in (1, 2, 7, 64):
        monkeypatch.setattr(recording, "EXPORT_CHUNK_FRAMES", chunk)
        assert poses2bvh(poses, tmp_path / f"{chunk}.bvh", 60.0) == n
        assert (tmp_path / f"{chunk}.bvh").read_bytes() == whole, chunk


def test_the_export_takes_memory_that_grows_by_bytes_a_pose(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Exporting an hour of poses built whole-motion arrays, the whole text and every
    pose (2.1 GB at one player-hour, about 6 kB more for each pose); it now keeps each
    pose's time and bone lengths and writes the frames a chunk at a time."""
    monkeypatch.setattr(recording, "EXPORT_CHUNK_FRAMES", 64)
    poses = walk_poses(1.0)

    def peak(n: int) -> int:
        path = write_looped(tmp_path / f"{n}.pcrec", poses, n)
        gc.collect()
        tracemalloc.start()
        try:
            with open_recording(path) as reader:
                paths = export_bvh(reader, tmp_path / f"out-{n}")
            used = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert read_bvh(paths["p-1"]).n_frames == n
        return used

    small, large = peak(500), peak(2000)
    assert large - small < 600_000, (small, large)  # 0.3 MB more; whole: 14.8 MB more


def test_a_reader_read_in_part_exports_the_rest(tmp_path: Path) -> None:
    path = tmp_path / "r.pcrec"
    w = RecordingWriter(path, url="ws://x/", room="r")
    for p in walk_poses(0.5):
        w.write(p)
    w.close()
    rec = read_recording(path)
    rest = export_bvh(recording.Recording(rec.header, rec.messages[5:]), tmp_path / "rest")
    with open_recording(path) as reader:
        for _ in zip(range(5), reader, strict=False):
            pass
        exported = export_bvh(reader, tmp_path / "out")
    assert read_bvh(exported["p-1"]).n_frames == 25
    assert exported["p-1"].read_bytes() == rest["p-1"].read_bytes()


def test_a_recording_that_changes_while_it_is_exported_is_an_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The export reads a reader's file twice: if the poses are not all there the second
    time, it says so (and leaves no file open)."""
    path, cut = tmp_path / "r.pcrec", tmp_path / "cut.pcrec"
    w = RecordingWriter(path, url="ws://x/", room="r")
    for p in walk_poses(0.5):
        w.write(p)
    w.close()
    cut.write_bytes(path.read_bytes()[: -len(path.read_bytes()) // 3])
    earlier = export_bvh(read_recording(path), tmp_path / "out")  # a good export before
    good = earlier["p-1"].read_bytes()
    monkeypatch.setattr(recording, "EXPORT_CHUNK_FRAMES", 4)  # the file is begun, then fails
    real_open = recording.open_recording
    monkeypatch.setattr(recording, "open_recording", lambda _: real_open(cut))
    with real_open(path) as reader, pytest.raises(RecordingError, match="changed while"):
        export_bvh(reader, tmp_path / "out")
    # The failed export left no broken file, and the earlier one as it was.
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["p-1.bvh"]
    assert earlier["p-1"].read_bytes() == good


def _recording_at_30_hz(path: Path, seconds: float = 1.0) -> None:
    """A welcome at 30 Hz, then poses 1/30 s apart."""
    w = RecordingWriter(path, url="ws://x/", room="r")
    w.write(Welcome(1, "rec", "s", "spectator", "r", 1.0, 30.0, 10, (Member("p-1", "P"),),
                    Limits()))  # fmt: skip
    for k, p in enumerate(walk_poses(seconds)[::2]):
        w.write(Pose(p.player, p.seq, 50.0 + k / 30.0, p.positions, p.rotations))
    w.close()


def test_a_closed_or_used_up_reader_is_an_error_not_an_empty_export(tmp_path: Path) -> None:
    """export_bvh of a reader that was closed, or read to its end, returned {} and wrote
    nothing, as if the recording held no poses."""
    path = tmp_path / "r.pcrec"
    _recording_at_30_hz(path)
    with open_recording(path) as reader:
        pass
    with pytest.raises(RecordingError, match="the reader is closed"):
        export_bvh(reader, tmp_path / "out")
    with open_recording(path) as reader:
        n = len(list(reader))
        with pytest.raises(RecordingError, match=f"read to its end \\({n} records\\)"):
            export_bvh(reader, tmp_path / "out")
    with open_recording(path) as reader:  # read up to its last record, not past it
        for _ in itertools.islice(reader, n):
            pass
        with pytest.raises(RecordingError, match="nothing is left to export"):
            export_bvh(reader, tmp_path / "out")
    assert list((tmp_path / "out").iterdir()) == []
    empty = tmp_path / "empty.pcrec"  # a recording of no records: nothing to export
    RecordingWriter(empty, url="ws://x/", room="r").close()
    with open_recording(empty) as reader:
        assert export_bvh(reader, tmp_path / "out") == {}


def test_a_reader_read_past_its_welcome_exports_at_the_welcomes_rate(tmp_path: Path) -> None:
    """A reader whose welcome (30 Hz) was read before the export exported at 60 Hz:
    the rate is the first welcome the reader gave, before the export or in it."""
    path = tmp_path / "r.pcrec"
    _recording_at_30_hz(path)
    rec = read_recording(path)
    want = export_bvh(recording.Recording(rec.header, rec.messages), tmp_path / "whole")
    assert "Frame Time: 0.03333333\n" in want["p-1"].read_text()
    rest = export_bvh(recording.Recording(rec.header, rec.messages[3:]), tmp_path / "rest")
    with open_recording(path) as reader:
        for _ in itertools.islice(reader, 3):  # the welcome and two poses
            pass
        assert reader.welcome_rate_hz == 30.0
        got = export_bvh(reader, tmp_path / "out")
    text = got["p-1"].read_text()
    assert "Frame Time: 0.03333333\n" in text and read_bvh(got["p-1"]).n_frames == 28
    assert text != rest["p-1"].read_text()  # a Recording without its welcome: 60 Hz


def _pipe(data: bytes) -> tuple[str, threading.Thread]:
    """A pipe carrying ``data`` (written by a thread), as a path: /dev/fd/N."""
    r, w = os.pipe()

    def write() -> None:
        with os.fdopen(w, "wb") as f:
            f.write(data)

    thread = threading.Thread(target=write, daemon=True)
    thread.start()
    return f"/dev/fd/{r}", thread


@pytest.mark.skipif(not Path("/dev/fd").is_dir(), reason="needs /dev/fd (Linux, macOS)")
def test_a_pipe_is_exported_as_the_file_is(tmp_path: Path) -> None:
    """A pipe (/dev/stdin, a process substitution) cannot be read twice: the second pass
    found nothing (and the first failed at its end, seeking to check the tail). The
    first pass copies it to a hidden file in the export's directory, removed after."""
    path = tmp_path / "r.pcrec"
    _recording_at_30_hz(path, 6.0)  # more than a pipe's buffer
    data = path.read_bytes()
    with open_recording(path) as reader:  # the same file, read in part the same way
        assert reader.regular
        for _ in itertools.islice(reader, 5):
            pass
        want = export_bvh(reader, tmp_path / "want")["p-1"].read_bytes()
    for tail in (b"", b"\x92\xcb\x41"):  # and a record cut short: ignored, as in a file
        where, thread = _pipe(data + tail)
        with open_recording(where) as reader:
            assert not reader.regular
            for _ in itertools.islice(reader, 5):  # read in part: the rest is exported
                pass
            got = export_bvh(reader, tmp_path / "out")
        thread.join()
        assert [p.name for p in (tmp_path / "out").iterdir()] == ["p-1.bvh"]  # no spool
        assert got["p-1"].read_bytes() == want
        assert read_bvh(got["p-1"]).n_frames == 180 - 4  # 6 s at 30 Hz, 4 poses read before
    where, thread = _pipe(data + b"garbage!")
    with open_recording(where) as reader, pytest.raises(RecordingError, match="corrupt"):
        export_bvh(reader, tmp_path / "bad")
    thread.join()
    assert list((tmp_path / "bad").iterdir()) == []
