"""The decoder's field validators (``fields.py``): each value checked on its own,
every refusal the code and the field path the spec names (BAD_FIELD, OUT_OF_RANGE,
NOT_NORMALISED), nil the same as absent."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from posecast_client import fields as f
from posecast_client.codec import decode, encode
from posecast_client.errors import ProtocolError
from posecast_client.protocol import LIMIT_RANGES, MAX_COORD_M, Frame, Limits, Member
from posecast_client.rotations import quat_normalize
from posecast_client.sites import MAX_SITES

IDENT = [0.0, 0.0, 0.0, 1.0]


def refused(code: str, field: str, call: Any, *args: Any) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        call(*args)
    assert (info.value.code, info.value.field) == (code, field), str(info.value)
    return info.value


def test_absent_and_nil_are_the_same_missing_field() -> None:
    for m in ({}, {"seq": None}):
        fields = f.Fields(m, "members[3].")
        assert not fields.has("seq") and fields.opt("seq", f.as_int, 0, 9) is None
        err = refused("BAD_FIELD", "members[3].seq", fields.req, "seq", f.as_int, 0, 9)
        assert "missing field members[3].seq" in str(err)
    assert f.Fields({"seq": 4}).req("seq", f.as_int, 0, 9) == 4
    refused("OUT_OF_RANGE", "at.seq", f.Fields({"seq": 10}, "at.").req, "seq", f.as_int, 0, 9)


def test_numbers() -> None:
    assert f.as_int(5, "n", 0, 9) == 5
    refused("BAD_FIELD", "n", f.as_int, 5.0, "n", 0, 9)  # a float is not an int
    refused("BAD_FIELD", "n", f.as_int, True, "n", 0, 9)  # nor a bool
    refused("OUT_OF_RANGE", "n", f.as_int, 10, "n", 0, 9)
    got = f.as_float(3, "t", 0.0, 5.0)
    assert got == 3.0 and type(got) is float  # an int on the wire reads as a float
    for bad in (math.nan, math.inf, -0.5, 5.5):
        refused("OUT_OF_RANGE", "t", f.as_float, bad, "t", 0.0, 5.0)
    refused("BAD_FIELD", "t", f.as_float, "1", "t", 0.0, 5.0)
    refused("BAD_FIELD", "t", f.as_float, True, "t", 0.0, 5.0)
    assert f.as_bool(False, "b") is False
    refused("BAD_FIELD", "b", f.as_bool, 0, "b")
    assert f.as_pose_rate(30, "rate_hz") == 30.0
    refused("OUT_OF_RANGE", "rate_hz", f.as_pose_rate, 40.0, "rate_hz")  # not a divisor of 60
    assert f.as_forecast(100, "ms") == 100.0
    refused("OUT_OF_RANGE", "ms", f.as_forecast, 100.5, "ms")


def test_strings_are_measured_in_utf8_bytes() -> None:
    assert f.as_str("é" * 4, "s", 0, 8) == "é" * 4  # 8 bytes
    refused("OUT_OF_RANGE", "s", f.as_str, "é" * 5, "s", 0, 8)  # 10 bytes, 5 chars
    refused("OUT_OF_RANGE", "s", f.as_str, "", "s", 1, 8)
    refused("BAD_FIELD", "s", f.as_str, b"x", "s", 0, 8)
    assert f.as_id("lobby-1:a_b.c", "room") == "lobby-1:a_b.c"
    refused("BAD_FIELD", "room", f.as_id, "lob by", "room")
    assert f.as_name("Ada Lovelace ✓", "name", 64) == "Ada Lovelace ✓"
    refused("BAD_FIELD", "name", f.as_name, "Ada\nL", "name", 64)
    refused("BAD_FIELD", "name", f.as_name, "Ada\x7f", "name", 64)
    assert f.as_enum("b", "k", ("a", "b")) == "b"
    assert "one of a, b" in str(refused("BAD_FIELD", "k", f.as_enum, "c", "k", ("a", "b")))


def test_layouts_are_named_or_tracker_sets() -> None:
    assert f.as_layout("hmd3", "layout") == "hmd3"
    sites = "head,left_hand,right_hand,left_foot"
    assert f.as_layout(sites, "layout") == sites
    err = refused("BAD_FIELD", "layout", f.as_layout, "head,nose", "layout")
    assert "a named layout: " in str(err)


def test_arrays_bins_and_points() -> None:
    assert f.as_array([1, 2], "watch", 2) == [1, 2]
    refused("OUT_OF_RANGE", "watch", f.as_array, [1, 2, 3], "watch", 2)
    refused("BAD_FIELD", "watch", f.as_array, (1,), "watch", 2)
    assert f.as_bin(bytes(4), "b", 4) == bytes(4)
    refused("BAD_FIELD", "b", f.as_bin, bytes(3), "b", 4)
    refused("BAD_FIELD", "b", f.as_bin, "abcd", "b", 4)
    assert f.as_data(b"", "data") == b""  # poses.data: any bin, read by records.py
    refused("BAD_FIELD", "data", f.as_data, [], "data")
    assert f.as_point([0, 1.5, -2], "point") == (0.0, 1.5, -2.0)
    refused("OUT_OF_RANGE", "point", f.as_point, [0, 2 * MAX_COORD_M, 0], "point")
    refused("OUT_OF_RANGE", "point", f.as_point, [0, math.nan, 0], "point")
    refused("BAD_FIELD", "point", f.as_point, [0, 0], "point")


def test_tracker_rows_renormalise_tracked_and_blank_untracked_slots() -> None:
    rows = [
        [0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0005],  # within the tolerance: renormalised
        [0.3, 1.0, 0.1, *IDENT],
        [5000.0, 0.0, 0.0, 0.0, 0.0, 0.0, 9.0],  # untracked: only its types are checked
        [0.0, 1.0, 0.0, *IDENT],
    ]
    pos, quat = f.as_trackers(rows, "trackers", 0b1011)
    np.testing.assert_allclose(quat[0], IDENT, rtol=0, atol=1e-15)
    assert pos[2].tolist() == [0.0, 0.0, 0.0] and quat[2].tolist() == IDENT
    refused("OUT_OF_RANGE", "trackers[2]", f.as_trackers, rows, "trackers", 0b1111)
    refused("BAD_FIELD", "trackers", f.as_trackers, rows[:3], "trackers", 0b0111)
    refused("BAD_FIELD", "trackers[1]", f.as_trackers, [rows[0], [0, 1], *rows[2:]], "trackers", 1)
    rows[0][6] = 2.0
    refused("NOT_NORMALISED", "trackers[0]", f.as_trackers, rows, "trackers", 0b0001)


def test_sites_count_and_mask() -> None:
    row = [0.0, 1.0, 0.0, *IDENT]
    pos, quat, valid = f.as_sites([row] * 3, "sites", None)
    assert valid == 0b111 and pos.shape == (3, 3) and quat.shape == (3, 4)
    assert f.as_sites([row] * 3, "sites", 0b101)[2] == 0b101
    refused("OUT_OF_RANGE", "valid", f.as_sites, [row] * 3, "sites", 0b1000)
    refused("BAD_FIELD", "sites", f.as_sites, [], "sites", None)
    refused("BAD_FIELD", "sites", f.as_sites, [row] * (MAX_SITES + 1), "sites", None)


def test_members_and_limits_name_the_nested_field() -> None:
    ann = {"player": "p-1", "name": "Ann"}
    assert f.as_members([ann], "members", Limits(), 1) == (Member("p-1", "Ann"),)
    refused("BAD_FIELD", "members[0].handle", f.as_members, [ann], "members", Limits(), 2)
    refused("BAD_FIELD", "members[1]", f.as_members, [ann, 3], "members", Limits(), 1)
    first = next(iter(LIMIT_RANGES))
    refused("BAD_FIELD", f"limits.{first}", f.as_limits, {}, "limits")
    assert f.as_limits({k: lo for k, (lo, _) in LIMIT_RANGES.items()}, "limits") == Limits(
        **{k: lo for k, (lo, _) in LIMIT_RANGES.items()}
    )


def test_frames_round_trip_with_renormalised_quaternions(rng: np.random.Generator) -> None:
    for _ in range(50):
        pos = rng.uniform(-5, 5, (4, 3))
        quat = quat_normalize(rng.normal(size=(4, 4)))
        valid = int(rng.integers(0, 16))
        out = decode(encode(Frame(int(rng.integers(0, 2**32)), 12.5, pos, quat, valid)))
        assert isinstance(out, Frame) and out.valid == valid
        for i in range(4):
            if valid >> i & 1:
                np.testing.assert_allclose(out.positions[i], pos[i])
                np.testing.assert_allclose(out.orientations[i], quat[i], atol=1e-15)
            else:  # untracked slots read as the origin with the identity rotation
                assert out.positions[i].tolist() == [0.0, 0.0, 0.0]
                assert out.orientations[i].tolist() == [0.0, 0.0, 0.0, 1.0]
