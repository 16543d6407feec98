"""The decoder's field validators (online.protocol.fields): each value checked on its own,
every refusal the code and the field path the spec names (BAD_FIELD, OUT_OF_RANGE,
NOT_NORMALISED), nil the same as absent."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from posecast.errors import ProtocolError
from posecast.online.protocol import fields as f
from posecast.online.protocol.messages import MAX_COORD_M

IDENT = [0.0, 0.0, 0.0, 1.0]


def _refused(code: str, field: str, call: Any, *args: Any, **kwargs: Any) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        call(*args, **kwargs)
    assert (info.value.code, info.value.field) == (code, field), str(info.value)
    return info.value


def test_absent_and_nil_are_the_same_missing_field() -> None:
    for m in ({}, {"seq": None}):
        err = _refused("BAD_FIELD", "members[3].seq", f.as_int, m, "seq", 0, 9, at="members[3].")
        assert "missing field members[3].seq" in str(err)


def test_numbers() -> None:
    assert f.as_int({"n": 5}, "n", 0, 9) == 5
    _refused("BAD_FIELD", "n", f.as_int, {"n": 5.0}, "n", 0, 9)  # a float is not an int
    _refused("BAD_FIELD", "n", f.as_int, {"n": True}, "n", 0, 9)  # nor a bool
    _refused("OUT_OF_RANGE", "n", f.as_int, {"n": 10}, "n", 0, 9)
    got = f.as_float({"t": 3}, "t", 0.0, 5.0)
    assert got == 3.0 and type(got) is float  # an int on the wire reads as a float
    for bad in (math.nan, math.inf, -0.5, 5.5):
        _refused("OUT_OF_RANGE", "t", f.as_float, {"t": bad}, "t", 0.0, 5.0)
    _refused("BAD_FIELD", "t", f.as_float, {"t": "1"}, "t", 0.0, 5.0)
    assert f.as_bool({"b": False}, "b") is False
    _refused("BAD_FIELD", "b", f.as_bool, {"b": 0}, "b")


def test_strings_are_measured_in_utf8_bytes() -> None:
    assert f.as_str({"s": "é" * 4}, "s", 8) == "é" * 4  # 8 bytes
    _refused("OUT_OF_RANGE", "s", f.as_str, {"s": "é" * 5}, "s", 8)  # 10 bytes, 5 chars
    _refused("OUT_OF_RANGE", "s", f.as_str, {"s": ""}, "s", 8)
    assert f.as_str({"s": ""}, "s", 8, min_bytes=0) == ""
    _refused("BAD_FIELD", "s", f.as_str, {"s": b"x"}, "s", 8)
    assert f.as_id({"room": "lobby-1:a_b.c"}, "room", 64) == "lobby-1:a_b.c"
    _refused("BAD_FIELD", "room", f.as_id, {"room": "lob by"}, "room", 64)
    assert f.as_name({"name": "Ada Lovelace ✓"}, "name", 64) == "Ada Lovelace ✓"
    _refused("BAD_FIELD", "name", f.as_name, {"name": "Ada\nL"}, "name", 64)
    _refused("BAD_FIELD", "name", f.as_name, {"name": "Ada\x7f"}, "name", 64)
    assert f.as_enum({"k": "b"}, "k", ("a", "b")) == "b"
    err = _refused("BAD_FIELD", "k", f.as_enum, {"k": "c"}, "k", ("a", "b"))
    assert "one of a, b" in str(err)
    assert f.CODE_PATTERN.fullmatch("BAD_FIELD") and not f.CODE_PATTERN.fullmatch("bad")


def test_containers() -> None:
    assert f.as_list({"l": [1, 2]}, "l", 2) == [1, 2]
    _refused("OUT_OF_RANGE", "l", f.as_list, {"l": [1, 2, 3]}, "l", 2)
    _refused("BAD_FIELD", "l", f.as_list, {"l": (1, 2)}, "l", 2)
    assert f.as_map({"m": {"a": 1}}, "m") == {"a": 1}
    _refused("BAD_FIELD", "m", f.as_map, {"m": [1]}, "m")
    assert f.as_bin({"b": b"\x00" * 4}, "b", 4) == b"\x00" * 4
    _refused("BAD_FIELD", "b", f.as_bin, {"b": b"\x00" * 3}, "b", 4)
    _refused("BAD_FIELD", "b", f.as_bin, {"b": "abcd"}, "b", 4)


def test_points_are_three_finite_numbers_within_the_wire_edge() -> None:
    assert f.as_point({"p": [1, 2.5, -3]}, "p") == (1.0, 2.5, -3.0)
    _refused("BAD_FIELD", "p", f.as_point, {"p": [1, 2]}, "p")
    _refused("BAD_FIELD", "p", f.as_point, {"p": [1, 2, "3"]}, "p")
    for bad in (MAX_COORD_M + 0.001, math.nan, -math.inf):
        _refused("OUT_OF_RANGE", "p", f.as_point, {"p": [0.0, bad, 0.0]}, "p")
    assert f.as_point({"p": [MAX_COORD_M, -MAX_COORD_M, 0]}, "p")[0] == MAX_COORD_M


def _rows(n: int) -> list[list[float]]:
    return [[float(i), 1.0, 0.0, *IDENT] for i in range(n)]


def test_trackers_are_renormalised_and_invalid_slots_read_as_origin_and_identity() -> None:
    rows = _rows(4)
    rows[1][3:] = [0.0, 0.0, 0.0, 1.0005]  # within the tolerance: renormalised
    rows[2] = [1e9, math.nan, 0.0, 7.0, 7.0, 7.0, 7.0]  # slot 2 invalid: not checked
    pos, quat = f.as_trackers({"trackers": rows}, "trackers", valid=0b1011)
    assert pos.shape == (4, 3) and quat.shape == (4, 4)
    np.testing.assert_array_equal(quat[1], IDENT)
    np.testing.assert_array_equal(pos[2], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(quat[2], IDENT)
    np.testing.assert_array_equal(pos[3], [3.0, 1.0, 0.0])


@pytest.mark.parametrize(
    ("row", "code"),
    [
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.1], "NOT_NORMALISED"),
        ([0.0, 1.0, 0.0, 0.0, 0.0, math.nan, 1.0], "OUT_OF_RANGE"),
        ([MAX_COORD_M * 2, 1.0, 0.0, *IDENT], "OUT_OF_RANGE"),
        ([0.0, 1.0, 0.0, *IDENT, 9.0], "BAD_FIELD"),
        ([0.0, "1", 0.0, *IDENT], "BAD_FIELD"),
    ],
)
def test_a_bad_tracker_row_is_named_by_its_index(row: list[Any], code: str) -> None:
    rows = _rows(4)
    rows[2] = row
    _refused(code, "trackers[2]", f.as_trackers, {"trackers": rows}, "trackers")


def test_trackers_are_four_and_sites_one_to_ten() -> None:
    _refused("BAD_FIELD", "trackers", f.as_trackers, {"trackers": _rows(3)}, "trackers")
    pos, quat, valid = f.as_sites({"sites": _rows(6)}, "sites", None)
    assert pos.shape == (6, 3) and quat.shape == (6, 4) and valid == 0b111111
    _, _, valid = f.as_sites({"sites": _rows(6)}, "sites", 0b000111)
    assert valid == 0b000111
    _refused("OUT_OF_RANGE", "valid", f.as_sites, {"sites": _rows(3)}, "sites", 0b1111)
    _refused("BAD_FIELD", "sites", f.as_sites, {"sites": []}, "sites", None)
    _refused("BAD_FIELD", "sites", f.as_sites, {"sites": _rows(11)}, "sites", None)
