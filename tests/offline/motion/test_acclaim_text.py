"""Reading Acclaim text (offline.motion.acclaim_text): lines whatever their ends, and
numbers whose every problem names the file and the line."""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest

from posecast.errors import AcclaimError
from posecast.offline.motion.acclaim_text import floats, is_float, read_lines


def test_lf_crlf_cr_and_gzip_give_the_same_lines(tmp_path: Path) -> None:
    want = ["# comment", ":units", "  mass 1.0", ""]
    for name, raw in {
        "lf.asf": b"# comment\n:units\n  mass 1.0\n\n",
        "crlf.asf": b"# comment\r\n:units\r\n  mass 1.0\r\n\r\n",
        "cr.asf": b"# comment\r:units\r  mass 1.0\r\r",
        "gz.asf": gzip.compress(b"# comment\n:units\n  mass 1.0\n\n"),
    }.items():
        (tmp_path / name).write_bytes(raw)
        assert read_lines(tmp_path / name) == want, name


def test_latin1_text_keeps_its_line_numbers(tmp_path: Path) -> None:
    """HDM05 comments carry Latin-1 names; byte 0x85 (NEL) is not a line end here."""
    path = tmp_path / "hdm.amc"
    path.write_bytes(b"# D:\\mocap\\caf\x85\n:FULLY-SPECIFIED\n1\n")
    assert read_lines(path) == ["# D:\\mocap\\caf\x85", ":FULLY-SPECIFIED", "1"]


def test_a_binary_file_is_named_with_the_line_of_its_first_nul(tmp_path: Path) -> None:
    path = tmp_path / "image.asf"
    path.write_bytes(b"one\ntwo\nthr\x00ee\n")
    with pytest.raises(AcclaimError, match="not a text file") as info:
        read_lines(path)
    assert info.value.file == str(path) and info.value.line == 3


def test_floats_reads_exactly_n_finite_numbers() -> None:
    assert floats(["1", "-2.5", "3e2"], 3, "axis", "a.asf", 7) == [1.0, -2.5, 300.0]
    cases = [
        (["1", "2"], "axis: expected 3 number\\(s\\), found 2"),
        (["1", "x", "3"], "axis: 'x' is not a number"),
        (["1", "inf", "3"], "axis: non-finite value"),
        (["nan", "0", "0"], "axis: non-finite value"),
    ]
    for tokens, why in cases:
        with pytest.raises(AcclaimError, match=why) as info:
            floats(tokens, 3, "axis", "a.asf", 7)
        assert info.value.file == "a.asf" and info.value.line == 7


def test_is_float() -> None:
    assert is_float("1") and is_float("-0.5e-3") and is_float("nan")
    assert not is_float("1,5") and not is_float("") and not is_float("rx")
