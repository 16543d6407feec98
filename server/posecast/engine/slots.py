"""Preallocated per-player arrays with swap-remove, so joins and leaves never re-batch.

Players occupy slots ``0 .. count-1`` of every array, contiguously, so one tick works
on plain views ``array[:count]`` (no gather, no copy). Removing a player moves the
last player into its slot. Capacity doubles when full (amortised, rare).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import DTypeLike, NDArray


class SlotArrays:
    def __init__(self, specs: Mapping[str, tuple[tuple[int, ...], DTypeLike]], capacity: int = 8):
        self.specs = dict(specs)
        self.capacity = max(1, capacity)
        self.count = 0
        self.arrays: dict[str, NDArray[Any]] = {
            k: np.zeros((self.capacity, *shape), dtype=dt) for k, (shape, dt) in self.specs.items()
        }

    def __getitem__(self, name: str) -> NDArray[Any]:
        return self.arrays[name]

    def view(self, name: str) -> NDArray[Any]:
        """The occupied part ``[:count]`` of one array (a view)."""
        return self.arrays[name][: self.count]

    def add(self) -> int:
        """Claim the next slot (zeroed) and return its index."""
        if self.count == self.capacity:
            self._grow(2 * self.capacity)
        slot = self.count
        for arr in self.arrays.values():
            arr[slot] = 0
        self.count += 1
        return slot

    def remove(self, slot: int) -> int | None:
        """Free ``slot``; returns the slot whose player moved into it, if any."""
        if not 0 <= slot < self.count:
            raise IndexError(slot)
        last = self.count - 1
        moved = None
        if slot != last:
            for arr in self.arrays.values():
                arr[slot] = arr[last]
            moved = last
        self.count -= 1
        return moved

    def _grow(self, capacity: int) -> None:
        for k, arr in self.arrays.items():
            new = np.zeros((capacity, *arr.shape[1:]), dtype=arr.dtype)
            new[: self.count] = arr[: self.count]
            self.arrays[k] = new
        self.capacity = capacity

    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values())
