"""The minimal BVH reader and writer: hand-checked FK, round trips, errors with lines."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from posecast_client.bvh import BvhWriter, parse_bvh, read_bvh, write_bvh
from posecast_client.errors import BvhError
from posecast_client.rotations import fk, quat2mat, quat_normalize
from posecast_client.skeleton import JOINT_NAMES, PARENTS, reference_offsets

TWO_BONES = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Arm
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 5 0 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 100 0  0 0 0   0 0 0
1 100 0  90 0 0  0 0 90
"""


def test_forward_kinematics_by_hand() -> None:
    bvh = parse_bvh(TWO_BONES)
    assert bvh.names == ("Hips", "Arm") and bvh.parents == (-1, 0)
    assert bvh.joints[1].end_site == (5.0, 0.0, 0.0) and bvh.frame_time_s == 0.5
    world, pos = bvh.fk(unit_m=0.01)
    np.testing.assert_allclose(pos[0], np.array([[0, 1, 0], [0.1, 1, 0]]), atol=1e-12)
    # frame 1: the hips turn 90 degrees about Z, so the arm (10 cm along +X) points up
    np.testing.assert_allclose(pos[1], [[0.01, 1, 0], [0.01, 1.1, 0]], atol=1e-12)
    # the arm's own 90 degrees about Y, after the parent's turn about Z
    np.testing.assert_allclose(world[1, 1] @ [1.0, 0, 0], [0, 0, -1], atol=1e-12)


def test_write_then_read_gives_the_same_motion(tmp_path: Path, rng: np.random.Generator) -> None:
    quat = quat_normalize(rng.normal(size=(6, 19, 4)) * [0.3, 0.3, 0.3, 1] + [0, 0, 0, 2])
    root = rng.normal(size=(6, 3))
    path = tmp_path / "canon.bvh.gz"
    write_bvh(path, names=JOINT_NAMES, parents=PARENTS, offsets=reference_offsets(),
              root_pos=root, local_quat=quat, frame_time_s=1 / 60)  # fmt: skip
    assert path.read_bytes()[:2] == b"\x1f\x8b"
    bvh = read_bvh(path)
    assert bvh.names == JOINT_NAMES and bvh.n_frames == 6
    _, pos = bvh.fk()
    _, want = fk(quat2mat(quat), root, reference_offsets(), PARENTS)
    np.testing.assert_allclose(pos, want, atol=2e-6)  # 6 decimals in the file


def test_a_motion_written_in_parts_is_the_file_written_whole(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    """BvhWriter writes the motion as it comes: any split of the frames gives the bytes
    write_bvh gives (gzip too: gzip.compress's with mtime 0), and the header's frame
    count is held to."""
    quat = quat_normalize(rng.normal(size=(50, 19, 4)))
    root = rng.normal(size=(50, 3))

    def writer(name: str, n_frames: int) -> BvhWriter:
        return BvhWriter(
            tmp_path / name,
            names=JOINT_NAMES,
            parents=PARENTS,
            offsets=reference_offsets(),
            n_frames=n_frames,
            frame_time_s=1 / 60,
        )

    for name in ("whole.bvh", "whole.bvh.gz"):
        write_bvh(tmp_path / name, names=JOINT_NAMES, parents=PARENTS, offsets=reference_offsets(),
                  root_pos=root, local_quat=quat, frame_time_s=1 / 60)  # fmt: skip
    whole = (tmp_path / "whole.bvh").read_bytes()
    assert (tmp_path / "whole.bvh.gz").read_bytes() == gzip.compress(whole, mtime=0)
    for part in (1, 7, 49):
        for name in ("parts.bvh", "parts.bvh.gz"):
            with writer(name, 50) as w:
                for k in range(0, 50, part):
                    w.write_frames(root[k : k + part], quat[k : k + part])
            suffix = name.removeprefix("parts")
            assert (tmp_path / name).read_bytes() == (tmp_path / f"whole{suffix}").read_bytes()
    w = writer("short.bvh", 3)
    w.write_frames(root[:2], quat[:2])
    with pytest.raises(ValueError, match="2 frames written, the header says 3"):
        w.close()
    with writer("long.bvh", 3) as w:
        with pytest.raises(ValueError, match="more than the 3 frames"):
            w.write_frames(root[:4], quat[:4])
        w.write_frames(root[:3], quat[:3])


def test_a_failed_write_leaves_no_broken_file_and_an_earlier_one_as_it_was(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    """BvhWriter truncated its target and wrote 'Frames: N' first, so an export that
    failed half way left a .bvh that claimed N frames and held fewer, over an earlier
    good one. It writes <name>.part beside it and renames it when whole."""
    quat = quat_normalize(rng.normal(size=(4, 19, 4)))
    root = rng.normal(size=(4, 3))

    def writer(path: Path, n_frames: int) -> BvhWriter:
        return BvhWriter(path, names=JOINT_NAMES, parents=PARENTS, offsets=reference_offsets(),
                         n_frames=n_frames, frame_time_s=1 / 60)  # fmt: skip

    for name in ("p.bvh", "p.bvh.gz"):
        path = tmp_path / name
        part = tmp_path / (name + ".part")
        write_bvh(path, names=JOINT_NAMES, parents=PARENTS, offsets=reference_offsets(),
                  root_pos=root[:2], local_quat=quat[:2], frame_time_s=1 / 60)  # fmt: skip
        good = path.read_bytes()
        assert not part.exists()
        w = writer(path, 4)  # an error on the way: abandoned
        w.write_frames(root[:2], quat[:2])
        assert part.exists() and path.read_bytes() == good  # written beside it
        w.abandon()
        assert not part.exists() and path.read_bytes() == good
        with pytest.raises(RuntimeError, match="on the way"), writer(path, 4) as w:
            w.write_frames(root[:1], quat[:1])
            raise RuntimeError("on the way")
        assert not part.exists() and path.read_bytes() == good
        w = writer(path, 4)  # fewer frames than the header says
        w.write_frames(root[:3], quat[:3])
        with pytest.raises(ValueError, match="3 frames written, the header says 4"):
            w.close()
        assert not part.exists() and path.read_bytes() == good
        with writer(path, 4) as w:  # a whole file replaces the earlier one
            w.write_frames(root, quat)
        assert not part.exists() and read_bvh(path).n_frames == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.bvh", "p.bvh.gz"]


def test_the_server_reads_what_the_sdk_writes(tmp_path: Path, rng: np.random.Generator) -> None:
    server_bvh = pytest.importorskip("posecast.offline.motion.bvh")
    quat = quat_normalize(rng.normal(size=(3, 19, 4)))
    path = tmp_path / "x.bvh"
    write_bvh(path, names=JOINT_NAMES, parents=PARENTS, offsets=reference_offsets(),
              root_pos=np.zeros((3, 3)), local_quat=quat, frame_time_s=1 / 60)  # fmt: skip
    theirs = server_bvh.read_bvh(path)
    assert theirs.names == JOINT_NAMES
    np.testing.assert_allclose(theirs.motion, read_bvh(path).motion)


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("HIERARCHY\nROOT a\n{\nOFFSET 0 0 x\n}\nMOTION\nFrames: 1\nFrame Time: 1\n\n", 4),
        ("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 1 Wrotation\n}\nMOTION\n", 5),
        ("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nBOGUS\n}\nMOTION\nFrames: 1\nFrame Time: 1\n", 5),
        ("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 1 Xposition\n}\nMOTION\n"
         "Frames: 2\nFrame Time: 0.1\n1\n", 10),  # truncated: the last line
        ("not bvh at all\nMOTION\n", 1),
    ],
)  # fmt: skip
def test_errors_name_the_line(text: str, line: int) -> None:
    with pytest.raises(BvhError) as info:
        parse_bvh(text, source="x.bvh")
    assert info.value.line == line and "x.bvh" in str(info.value)


def test_missing_motion_and_files(tmp_path: Path) -> None:
    with pytest.raises(BvhError):
        parse_bvh("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\n}\n")
    with pytest.raises(BvhError):
        read_bvh(tmp_path / "nope.bvh")
