"""BVH reading and writing: odd channel layouts, gzip, round trips, and errors by line."""

from __future__ import annotations

import gzip
import itertools
from pathlib import Path

import numpy as np
import pytest

from posecast.errors import BvhError, DataError
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import axis_mat
from posecast.offline.motion.bvh import Bvh, parse_bvh, read_bvh, write_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.skeleton import JOINT_NAMES, PARENTS, reference_offsets

# A small hand-written file: rotation channels in unusual orders, position channels
# on a non-root joint, End Sites. Line numbers matter to the error tests below.
SMALL = """\
HIERARCHY
ROOT Hips
{
\tOFFSET 1.0 2.0 3.0
\tCHANNELS 6 Xposition Yposition Zposition Xrotation Zrotation Yrotation
\tJOINT Chest
\t{
\t\tOFFSET 0.0 10.0 0.0
\t\tCHANNELS 4 Zposition Yrotation Xposition Zrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0.0 5.0 0.0
\t\t}
\t}
\tJOINT Leg
\t{
\t\tOFFSET 2.0 -1.0 0.0
\t\tCHANNELS 3 Yrotation Xrotation Zrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0.0 -8.0 0.0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.04
0 0 0 0 0 0 0 0 0 0 0 0 0
10 20 30 90 0 0 1 0 2 0 0 0 0
0 0 0 30 40 50 0 60 0 70 10 20 -30
"""
SMALL_LINES = 30  # the file's last line, the third frame


def edited(line: int, new: str | None) -> str:
    """``SMALL`` with 1-based ``line`` replaced by ``new``, or cut before it if None."""
    lines = SMALL.splitlines()
    if new is None:
        lines = lines[: line - 1]
    else:
        lines[line - 1] = new
    return "\n".join(lines) + "\n"


def rx(deg: float) -> np.ndarray:
    return axis_mat("X", np.deg2rad(deg))


def ry(deg: float) -> np.ndarray:
    return axis_mat("Y", np.deg2rad(deg))


def rz(deg: float) -> np.ndarray:
    return axis_mat("Z", np.deg2rad(deg))


def bvh_positions(bvh: Bvh) -> np.ndarray:
    """World joint positions ``(F, J, 3)`` of a parsed file, in file units."""
    rot, trans = bvh.local_transforms()
    # The root's translation already holds its offset plus its position channels.
    return fk_mat(rot, np.zeros(3), trans, bvh.parents)[1]


# --- reading ------------------------------------------------------------------------


def test_parse_hierarchy() -> None:
    bvh = parse_bvh(SMALL, source="small.bvh")
    assert bvh.names == ("Hips", "Chest", "Leg")
    assert bvh.parents == (-1, 0, 0)
    assert bvh.source == "small.bvh"
    np.testing.assert_array_equal(bvh.offsets(), [[1, 2, 3], [0, 10, 0], [2, -1, 0]])
    hips, chest, leg = bvh.joints
    assert hips.channels[3:] == ("Xrotation", "Zrotation", "Yrotation")
    assert (hips.rotation_order, chest.rotation_order, leg.rotation_order) == ("XZY", "YZ", "YXZ")
    assert chest.channels == ("Zposition", "Yrotation", "Xposition", "Zrotation")
    assert (hips.end_site, chest.end_site, leg.end_site) == (None, (0.0, 5.0, 0.0), (0, -8, 0))
    assert (hips.line, chest.line, leg.line) == (2, 6, 15)
    assert bvh.index("Leg") == 2


def test_parse_motion() -> None:
    bvh = parse_bvh(SMALL)
    assert bvh.n_frames == 3
    assert bvh.motion.shape == (3, 13)
    assert bvh.frame_time_s == pytest.approx(0.04)
    assert bvh.fps == pytest.approx(25.0)
    np.testing.assert_array_equal(bvh.motion[2, -3:], [10, 20, -30])


def test_local_transforms_follow_the_channel_order() -> None:
    rot, trans = parse_bvh(SMALL).local_transforms()
    assert rot.shape == (3, 3, 3, 3)
    np.testing.assert_allclose(rot[0], np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-15)
    # Rotations compose in file order: "Xrotation Zrotation Yrotation" is Rx Rz Ry.
    np.testing.assert_allclose(rot[2, 0], rx(30) @ rz(40) @ ry(50), atol=1e-12)
    np.testing.assert_allclose(rot[2, 1], ry(60) @ rz(70), atol=1e-12)
    np.testing.assert_allclose(rot[2, 2], ry(10) @ rx(20) @ rz(-30), atol=1e-12)
    # Position channels add to the offset, whatever their place in the list.
    np.testing.assert_allclose(trans[1, 0], [11, 22, 33])
    np.testing.assert_allclose(trans[1, 1], [2, 10, 1])
    np.testing.assert_allclose(trans[1, 2], [2, -1, 0])


def test_positions_of_a_worked_frame() -> None:
    """Frame 2: hips at (11, 22, 33) turned 90 degrees about X, so local +Y is world +Z."""
    pos = bvh_positions(parse_bvh(SMALL))
    np.testing.assert_allclose(pos[1], [[11, 22, 33], [13, 21, 43], [13, 22, 32]], atol=1e-12)


def test_read_plain_and_gzip(tmp_path: Path) -> None:
    plain = tmp_path / "small.bvh"
    plain.write_text(SMALL)
    packed = tmp_path / "small.bvh.gz"
    packed.write_bytes(gzip.compress(SMALL.encode()))
    # Compression is found by content, not by the name.
    misnamed = tmp_path / "packed_without_suffix.bvh"
    misnamed.write_bytes(gzip.compress(SMALL.encode()))
    want = parse_bvh(SMALL)
    for path in (plain, packed, misnamed):
        bvh = read_bvh(path)
        assert bvh.source == str(path)
        assert bvh.joints == want.joints
        np.testing.assert_array_equal(bvh.motion, want.motion)


def test_read_tolerates_blank_lines_and_crlf() -> None:
    text = SMALL.replace("\n", "\r\n").replace("MOTION", "\r\nMOTION")
    text = text.replace("Frame Time: 0.04\r\n", "Frame Time: 0.04\r\n\r\n")
    bvh = parse_bvh(text)
    np.testing.assert_array_equal(bvh.motion, parse_bvh(SMALL).motion)


# --- writing --------------------------------------------------------------------------


def write_walk(path: Path, clip: CanonicalClip, order: str = "ZYX", scale: float = 1.0) -> None:
    write_bvh(
        path,
        names=JOINT_NAMES,
        parents=PARENTS,
        offsets=reference_offsets(),
        root_pos=clip.root_pos,
        local_quat=clip.local_quat,
        frame_time_s=1.0 / clip.fps,
        order=order,
        scale=scale,
    )


@pytest.mark.parametrize("order", ["".join(p) for p in itertools.permutations("XYZ")])
def test_write_read_round_trip(tmp_path: Path, walk: CanonicalClip, order: str) -> None:
    path = tmp_path / "walk.bvh"
    write_walk(path, walk, order)
    bvh = read_bvh(path)
    assert bvh.names == JOINT_NAMES
    assert bvh.parents == PARENTS
    assert bvh.n_frames == walk.n_frames
    assert bvh.fps == pytest.approx(walk.fps, rel=1e-6)
    assert bvh.joints[0].channels == (
        "Xposition",
        "Yposition",
        "Zposition",
        *(f"{a}rotation" for a in order),
    )
    assert all(j.rotation_order == order for j in bvh.joints)
    _, want = walk.fk()
    np.testing.assert_allclose(bvh_positions(bvh), want, atol=1e-3)


def test_write_gzip_in_centimetres(tmp_path: Path, walk: CanonicalClip) -> None:
    path = tmp_path / "walk.bvh.gz"
    write_walk(path, walk, "ZXY", scale=100.0)
    assert path.read_bytes()[:2] == b"\x1f\x8b"
    bvh = read_bvh(path)
    np.testing.assert_allclose(bvh.offsets(), reference_offsets() * 100.0, atol=1e-6)
    _, want = walk.fk()
    np.testing.assert_allclose(bvh_positions(bvh) / 100.0, want, atol=1e-3)


def test_write_gives_every_leaf_an_end_site(tmp_path: Path, walk: CanonicalClip) -> None:
    path = tmp_path / "walk.bvh"
    write_walk(path, walk)
    bvh = read_bvh(path)
    leaves = {j.name for i, j in enumerate(bvh.joints) if i not in bvh.parents}
    assert leaves == {"HEAD", "LEFT_HAND", "RIGHT_HAND", "LEFT_TOE", "RIGHT_TOE"}
    for joint in bvh.joints:
        assert (joint.end_site is not None) == (joint.name in leaves)


# --- errors ---------------------------------------------------------------------------


def read_error(tmp_path: Path, text: str | bytes, name: str = "bad.bvh") -> BvhError:
    path = tmp_path / name
    if isinstance(text, str):
        path.write_text(text)
    else:
        path.write_bytes(text)
    with pytest.raises(BvhError) as info:
        read_bvh(path)
    assert info.value.file == str(path)
    return info.value


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        (edited(30, None), 29, "header says 3 frames, found 2"),
        (edited(26, "Frames: 5"), 30, "header says 5 frames, found 3"),
        (edited(25, None), 24, "no MOTION section"),
        (edited(12, None), 11, "no MOTION section"),
        ("hello\nworld\n", 1, "not a BVH file"),
        ('\n\n{"joints": []}\n', 3, "not a BVH file"),
        ("", 1, "not a BVH file"),
        (edited(29, "10 20 30 90 0 0 1 0 2 0 0 0"), 29, "expected 13 values, found 12"),
        (edited(30, "0 0 0 30 40 50 0 60 0 70 10 20 -30 4"), 30, "expected 13 values, found 14"),
        (edited(28, "0 0 0 0 0 0 0 0 0 abc 0 0 0"), 28, "non-numeric"),
        (edited(30, "0 0 0 30 40 50 0 60 0 nan 10 20 -30"), 30, "non-finite"),
        (edited(18, "\t\tCHANNELS 3 Yrotation Wrotation Zrotation"), 18, "unknown channel"),
        (edited(9, "\t\tCHANNELS four Zposition"), 9, "bad channel count"),
        (edited(8, "\t\tOFFSET 0.0 ten 0.0"), 8, "expected a number"),
        (edited(15, "\tJOINT Chest"), 15, "duplicate joint name 'Chest'"),
        (edited(15, "\tJOINTS Leg"), 15, "unexpected 'JOINTS'"),
        (edited(2, "JOINT Hips"), 2, "expected 'ROOT'"),
        (edited(24, "}\nROOT Other"), 25, "only one ROOT"),
        (edited(26, "Frames: many"), 26, "bad Frames"),
        (edited(27, "FrameTime 0.04"), 27, "expected 'Frame Time:'"),
        (edited(26, "Frames: -1"), 26, "Frames must be >= 0"),
        (edited(27, "Frame Time: 0"), 27, "Frame Time must be > 0"),
        (edited(27, "Frame Time: fast"), 27, "bad Frame Time value 'fast'"),
        (edited(26, "\nFrames: x"), 27, "bad Frames value 'x'"),
    ],
)
def test_bad_file_names_file_and_line(tmp_path: Path, text: str, line: int, message: str) -> None:
    err = read_error(tmp_path, text)
    assert err.line == line
    assert message in err.detail
    assert str(err).startswith(f"{err.file}:{line}: ")
    assert isinstance(err, DataError)
    assert err.code == "BVH_INVALID"


def test_garbage_gzip(tmp_path: Path) -> None:
    packed = gzip.compress(SMALL.encode())
    corrupt = packed[:10] + bytes(range(256))  # a valid header, then noise
    err = read_error(tmp_path, corrupt, "bad.bvh.gz")
    assert "gzip" in err.detail
    assert err.line is None


def test_truncated_gzip(tmp_path: Path) -> None:
    packed = gzip.compress(SMALL.encode())
    err = read_error(tmp_path, packed[: len(packed) // 2], "cut.bvh.gz")
    assert "gzip" in err.detail


def test_binary_file(tmp_path: Path, rng: np.random.Generator) -> None:
    """Arbitrary bytes decode as latin-1 text, then fail the header check."""
    err = read_error(tmp_path, b"\x89PNG\r\n" + rng.bytes(64), "image.bvh")
    assert err.line == 1
    assert "not a BVH file" in err.detail


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.bvh"
    with pytest.raises(BvhError, match="cannot read") as info:
        read_bvh(path)
    assert info.value.file == str(path)
