"""The AMC parser (offline.motion.acclaim_amc): bones missing from a frame, its fast and
line-by-line readings, and every error naming the file and the line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from posecast.errors import AcclaimError
from posecast.offline.motion.acclaim import read_acclaim
from posecast.offline.motion.acclaim_amc import parse_amc, read_amc
from posecast.offline.motion.acclaim_asf import read_asf

from .acclaim_fixtures import GOLDEN_AMC, GOLDEN_FRAMES, write_text


def test_bones_missing_from_a_frame_hold_zeros(tmp_path: Path, golden) -> None:
    asf = read_asf(golden[0])
    lines = GOLDEN_AMC.splitlines()
    # Drop the arm from frame 3 and the root and hand from frame 4.
    at3, at4 = lines.index("3"), lines.index("4")
    drop = {at3 + 3, at4 + 1, at4 + 5}
    assert [lines[i].split()[0] for i in sorted(drop)] == ["arm", "root", "hand"]
    sparse = [ln for i, ln in enumerate(lines) if i not in drop]
    amc = parse_amc(sparse, asf, source="sparse.amc")
    full = parse_amc(lines, asf, source="full.amc")
    np.testing.assert_array_equal(amc.values["arm"][2], [0.0, 0.0])
    np.testing.assert_array_equal(amc.values["root"][3], np.zeros(6))
    np.testing.assert_array_equal(amc.values["hand"][3], np.zeros(3))
    for name, values in full.values.items():  # everything else as given
        keep = np.ones(GOLDEN_FRAMES, bool)
        keep[{"arm": [2], "root": [3], "hand": [3]}.get(name, [])] = False
        np.testing.assert_array_equal(amc.values[name][keep], values[keep])
    # and a missing bone is the rest pose: the rotation identity, not the last frame's
    p = write_text(tmp_path / "sparse_01.amc", "\n".join(sparse) + "\n")
    bvh = read_acclaim(golden[0], p)
    rot, _ = bvh.local_transforms()
    np.testing.assert_allclose(rot[2, bvh.index("arm")], np.eye(3), atol=1e-12)


def test_the_fast_and_the_line_by_line_reading_agree(golden) -> None:
    asf = read_asf(golden[0])
    lines = GOLDEN_AMC.splitlines()
    fast = parse_amc(lines, asf)
    # A comment between frames is legal and sends the reader down the careful path.
    slow = parse_amc([*lines[:10], "# a comment", *lines[10:]], asf)
    np.testing.assert_array_equal(fast.frame_numbers, slow.frame_numbers)
    for name in fast.values:
        np.testing.assert_array_equal(fast.values[name], slow.values[name])


def _amc_line(fragment: str, nth: int = 0) -> int:
    hits = [i for i, ln in enumerate(GOLDEN_AMC.splitlines(), 1) if ln.startswith(fragment)]
    return hits[nth]


AMC_ERRORS = {
    "unknown bone": (("arm", 1), "elbow 1 2", "unknown bone 'elbow'"),
    "too few values": (("hand", 2), "hand 1 2", "expected 3 value(s), found 2"),
    "non-numeric": (("spine", 3), "spine 1 abc 3", "'abc' is not a number"),
    "non-finite": (("forearm", 4), "forearm nan", "non-finite"),
    "twice in a frame": (("forearm", 0), "spine 1 2 3", "appears twice in frame 1"),
    "frame gap": (("4", 0), "7", "frame 7 follows frame 3"),
    "bone before frame 1": (("1", 0), "root 0 0 0 0 0 0", "expected a frame number"),
}


@pytest.mark.parametrize("kind", list(AMC_ERRORS))
@pytest.mark.parametrize("gz", [False, True], ids=["plain", "gzip"])
def test_amc_errors_name_file_and_line(tmp_path: Path, golden, kind: str, gz: bool) -> None:
    (bone, nth), new, why = AMC_ERRORS[kind]
    line = _amc_line(bone, nth)
    lines = GOLDEN_AMC.splitlines()
    lines[line - 1] = new
    path = write_text(tmp_path / ("bad_01.amc" + (".gz" if gz else "")), "\n".join(lines), gz=gz)
    with pytest.raises(AcclaimError) as info:
        read_acclaim(golden[0], path)
    exc = info.value
    assert exc.file == str(path)
    assert exc.line == line, str(exc)
    assert f"{path}:{line}: " in str(exc)
    assert why in str(exc)


def test_amc_file_errors(tmp_path: Path, golden) -> None:
    asf = read_asf(golden[0])
    no_frames = write_text(tmp_path / "empty.amc", ":FULLY-SPECIFIED\n:DEGREES\n")
    with pytest.raises(AcclaimError, match="no frames") as info:
        read_amc(no_frames, asf)
    assert info.value.line == 2
    broken = tmp_path / "broken.amc.gz"
    broken.write_bytes(b"\x1f\x8b" + bytes(range(200)))
    with pytest.raises(AcclaimError, match="corrupt gzip") as info:
        read_amc(broken, asf)
    assert info.value.file == str(broken) and info.value.line is None
    with pytest.raises(AcclaimError, match="cannot read file"):
        read_amc(tmp_path / "absent.amc", asf)
    binary = tmp_path / "image.amc"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    with pytest.raises(AcclaimError, match="not a text file"):
        read_amc(binary, asf)
