"""Preallocated per-player arrays with swap-remove, so joins and leaves never re-batch.

Players occupy slots ``0 .. count-1`` of every array, contiguously, so one tick works
on plain views (no gather, no copy). An array is either per player, shaped
``(capacity, ...)``, or a ring of per-player frames shaped ``(ring, capacity, ...)``:
ring row ``k`` of all players is then one contiguous block that ONNX Runtime can read
from and write into directly. Removing a player moves the last player into its slot.
Capacity doubles when full (amortised, rare).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import DTypeLike, NDArray

# name -> (per-player shape, dtype[, ring length]); no ring length: a per-player array
Spec = tuple[tuple[int, ...], DTypeLike] | tuple[tuple[int, ...], DTypeLike, int]


class SlotArrays:
    def __init__(self, specs: Mapping[str, Spec], capacity: int = 8):
        self.specs: dict[str, tuple[tuple[int, ...], DTypeLike, int]] = {
            k: (v[0], v[1], v[2] if len(v) == 3 else 0) for k, v in specs.items()
        }
        self.capacity = max(1, capacity)
        self.count = 0
        self.arrays: dict[str, NDArray[Any]] = {
            k: np.zeros(self._shape(k, self.capacity), dtype=dt)
            for k, (_, dt, _) in self.specs.items()
        }

    def _shape(self, name: str, capacity: int) -> tuple[int, ...]:
        shape, _, ring = self.specs[name]
        return (ring, capacity, *shape) if ring else (capacity, *shape)

    def _axis(self, name: str) -> int:
        return 1 if self.specs[name][2] else 0

    def __getitem__(self, name: str) -> NDArray[Any]:
        return self.arrays[name]

    def view(self, name: str) -> NDArray[Any]:
        """The occupied part of a per-player array, ``[:count]`` (a view)."""
        if self._axis(name):
            raise ValueError(f"{name} is a ring; use row()")
        return self.arrays[name][: self.count]

    def row(self, name: str, k: int) -> NDArray[Any]:
        """Ring row ``k`` of all occupied slots, ``[k, :count]`` (a contiguous view)."""
        return self.arrays[name][k, : self.count]

    def add(self) -> int:
        """Claim the next slot (zeroed) and return its index."""
        if self.count == self.capacity:
            self._grow(2 * self.capacity)
        slot = self.count
        for name, arr in self.arrays.items():
            if self._axis(name):
                arr[:, slot] = 0
            else:
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
            for name, arr in self.arrays.items():
                if self._axis(name):
                    arr[:, slot] = arr[:, last]
                else:
                    arr[slot] = arr[last]
            moved = last
        self.count -= 1
        return moved

    def _grow(self, capacity: int) -> None:
        for name, arr in self.arrays.items():
            new = np.zeros(self._shape(name, capacity), dtype=arr.dtype)
            if self._axis(name):
                new[:, : self.count] = arr[:, : self.count]
            else:
                new[: self.count] = arr[: self.count]
            self.arrays[name] = new
        self.capacity = capacity

    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays.values())
