"""SlotArrays: contiguous per-player slots, swap-remove on leave, doubling growth."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.online.engine.slots import SlotArrays


def make(capacity: int = 2) -> SlotArrays:
    return SlotArrays({"a": ((3,), np.float32), "b": ((2, 2), np.int64)}, capacity)


def fill(s: SlotArrays, slot: int, value: int) -> None:
    s["a"][slot] = value
    s["b"][slot] = value * 10


def test_add_claims_zeroed_contiguous_slots() -> None:
    s = make()
    assert [s.add(), s.add()] == [0, 1]
    assert s.count == 2
    assert s.view("a").shape == (2, 3)
    assert s["b"].dtype == np.int64
    fill(s, 1, 7)
    assert s.remove(1) is None
    # The freed slot is handed out again, cleared of the old player's data.
    assert s.add() == 1
    np.testing.assert_array_equal(s["a"][1], 0)
    np.testing.assert_array_equal(s["b"][1], 0)


def test_view_is_the_occupied_part_and_writes_through() -> None:
    s = make(capacity=4)
    s.add()
    s.add()
    v = s.view("a")
    assert v.shape == (2, 3)
    v[...] = 5.0
    np.testing.assert_array_equal(s["a"][:2], 5.0)
    np.testing.assert_array_equal(s["a"][2:], 0.0)


def test_swap_remove_moves_the_last_player_into_the_hole() -> None:
    s = make(capacity=4)
    for value in (1, 2, 3, 4):
        fill(s, s.add(), value)
    assert s.remove(1) == 3  # the player in slot 3 now lives in slot 1
    assert s.count == 3
    np.testing.assert_array_equal(s.view("a")[:, 0], [1, 4, 3])
    np.testing.assert_array_equal(s.view("b")[:, 0, 0], [10, 40, 30])
    assert s.remove(2) is None  # removing the last slot moves nobody
    np.testing.assert_array_equal(s.view("a")[:, 0], [1, 4])
    with pytest.raises(IndexError):
        s.remove(2)
    with pytest.raises(IndexError):
        s.remove(-1)


def test_growth_keeps_data() -> None:
    s = make(capacity=2)
    for value in range(1, 6):  # 2 -> 4 -> 8
        fill(s, s.add(), value)
    assert s.capacity == 8
    assert s.count == 5
    np.testing.assert_array_equal(s.view("a")[:, 2], [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(s.view("b")[:, 1, 1], [10, 20, 30, 40, 50])
    assert s["a"].dtype == np.float32
    assert s.nbytes() == 8 * (3 * 4 + 4 * 8)


def test_capacity_is_at_least_one() -> None:
    s = SlotArrays({"a": ((1,), np.float64)}, capacity=0)
    assert s.capacity == 1
    s.add()
    s.add()
    assert s.capacity == 2
