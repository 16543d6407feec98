"""Field validators for the decoder: one msgpack value in, a checked Python value out.

Each takes the message map, the key, the value's bounds and ``at`` (a path prefix
for nested maps such as ``members[3].``), and raises the :class:`ProtocolError` the
spec names: BAD_FIELD for a missing field or a wrong type, shape or value,
OUT_OF_RANGE for a number outside its range (NaN and infinities included) or a
string of the wrong length, NOT_NORMALISED for a quaternion off unit length.
A nil value is the same as an absent field.
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.errors import BadFieldError, NotNormalisedError, OutOfRangeError
from posecast.online.protocol.messages import ALL_TRACKERS_VALID, MAX_COORD_M, QUAT_TOLERANCE
from posecast.tracking.features import NUM_TRACKERS
from posecast.tracking.sites import NUM_SITES

F64 = NDArray[np.float64]
Map = dict[str, Any]

ID_PATTERN = re.compile(r"[A-Za-z0-9_.:-]+")  # room names, player and session ids
CODE_PATTERN = re.compile(r"[A-Z][A-Z0-9_]{0,31}")  # error codes
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")  # not allowed in display names
_NUMBER = frozenset({float, int})
_TRACKER_WIDTH = 7  # px py pz qx qy qz qw
_ABSENT_ROW = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)  # origin, identity rotation
# | |q| - 1 | <= QUAT_TOLERANCE, compared on the squared norm to skip a sqrt.
_NORM2_LO, _NORM2_HI = (1.0 - QUAT_TOLERANCE) ** 2, (1.0 + QUAT_TOLERANCE) ** 2


def _get(m: Map, key: str, at: str) -> Any:
    v = m.get(key)
    if v is None:
        raise BadFieldError(f"missing field {at}{key}", field=at + key)
    return v


def _bad(path: str, expected: str) -> BadFieldError:
    return BadFieldError(f"{path}: expected {expected}", field=path)


def as_int(m: Map, key: str, lo: int, hi: int, *, at: str = "") -> int:
    v = _get(m, key, at)
    if type(v) is not int:
        raise _bad(at + key, "an integer")
    if not lo <= v <= hi:
        raise OutOfRangeError(f"{at}{key}={v} outside [{lo}, {hi}]", field=at + key)
    return v


def as_float(m: Map, key: str, lo: float, hi: float, *, at: str = "") -> float:
    """A number (float64, float32 or int on the wire) in ``[lo, hi]``, finite."""
    v = _get(m, key, at)
    t = type(v)
    if t is not float:
        if t is not int:
            raise _bad(at + key, "a number")
        v = float(v)
    if not lo <= v <= hi:  # NaN fails too
        raise OutOfRangeError(f"{at}{key}={v} outside [{lo}, {hi}]", field=at + key)
    return float(v)


def as_bool(m: Map, key: str, *, at: str = "") -> bool:
    v = _get(m, key, at)
    if type(v) is not bool:
        raise _bad(at + key, "a boolean")
    return v


def as_str(m: Map, key: str, max_bytes: int, *, min_bytes: int = 1, at: str = "") -> str:
    """A string of ``min_bytes``..``max_bytes`` UTF-8 bytes."""
    v = _get(m, key, at)
    if type(v) is not str:
        raise _bad(at + key, "a string")
    n = len(v)  # code points: each is 1..4 bytes, so only measure when it matters
    if n * 4 > max_bytes or n < min_bytes:
        n = len(v.encode())
    if not min_bytes <= n <= max_bytes:
        raise OutOfRangeError(
            f"{at}{key} is {n} bytes, not {min_bytes}..{max_bytes}", field=at + key
        )
    return v


def as_id(m: Map, key: str, max_bytes: int, *, at: str = "") -> str:
    """A room name or id: 1..max_bytes of ``[A-Za-z0-9_.:-]``."""
    v = as_str(m, key, max_bytes, at=at)
    if ID_PATTERN.fullmatch(v) is None:
        raise _bad(at + key, "only A-Z a-z 0-9 _ . : -")
    return v


def as_name(m: Map, key: str, max_bytes: int, *, at: str = "") -> str:
    """A display name: 1..max_bytes, no control characters."""
    v = as_str(m, key, max_bytes, at=at)
    if _CONTROL.search(v) is not None:
        raise _bad(at + key, "no control characters")
    return v


def as_enum(m: Map, key: str, options: tuple[str, ...], *, at: str = "") -> str:
    v = _get(m, key, at)
    if type(v) is not str or v not in options:
        raise _bad(at + key, "one of " + ", ".join(options))
    return v


def as_list(m: Map, key: str, max_len: int, *, at: str = "") -> list[Any]:
    v = _get(m, key, at)
    if type(v) is not list:
        raise _bad(at + key, "an array")
    if len(v) > max_len:
        raise OutOfRangeError(f"{at}{key} has {len(v)} items, max {max_len}", field=at + key)
    return v


def as_map(m: Map, key: str, *, at: str = "") -> Map:
    v = _get(m, key, at)
    if type(v) is not dict:
        raise _bad(at + key, "a map")
    return v


def as_bin(m: Map, key: str, size: int, *, at: str = "") -> bytes:
    v = _get(m, key, at)
    if type(v) is not bytes or len(v) != size:
        raise _bad(at + key, f"bin of {size} bytes")
    return v


def as_point(m: Map, key: str, *, at: str = "") -> tuple[float, float, float]:
    """A world position ``[x, y, z]`` in metres, each within +-MAX_COORD_M."""
    v = _get(m, key, at)
    path = at + key
    if type(v) is not list or len(v) != 3 or not _NUMBER.issuperset(map(type, v)):
        raise _bad(path, "an array of 3 numbers")
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    if not (abs(x) <= MAX_COORD_M and abs(y) <= MAX_COORD_M and abs(z) <= MAX_COORD_M):
        raise OutOfRangeError(f"{path} outside +-{MAX_COORD_M} m or not finite", field=path)
    return x, y, z


def as_trackers(m: Map, key: str, valid: int = ALL_TRACKERS_VALID) -> tuple[F64, F64]:
    """4 trackers ``[px, py, pz, qx, qy, qz, qw]`` -> ``(pos (4, 3), quat (4, 4))``.

    Slots whose ``valid`` bit is clear are not range-checked; they come back as the
    origin with the identity rotation. Quaternions within QUAT_TOLERANCE of unit
    length are renormalised. Plain Python on purpose: for 4 x 7 numbers it is about
    three times faster than the same checks as numpy reductions.
    """
    rows = _get(m, key, "")
    if type(rows) is not list or len(rows) != NUM_TRACKERS:
        raise _bad(key, f"an array of {NUM_TRACKERS} trackers")
    return _tracker_rows(rows, key, valid)


def _tracker_rows(rows: list[Any], key: str, valid: int) -> tuple[F64, F64]:
    """Checked rows ``[x, y, z, qx, qy, qz, qw]`` -> ``(xyz (n, 3), quat (n, 4))``;
    see :func:`as_trackers`. A site row's ``xyz`` is a position or an acceleration:
    the same bounds hold for both."""
    out: list[tuple[float, ...]] = []
    for i, row in enumerate(rows):
        if (
            type(row) is not list
            or len(row) != _TRACKER_WIDTH
            or not _NUMBER.issuperset(map(type, row))
        ):
            raise _bad(f"{key}[{i}]", f"an array of {_TRACKER_WIDTH} numbers")
        if not valid >> i & 1:
            out.append(_ABSENT_ROW)
            continue
        px, py, pz, qx, qy, qz, qw = row
        if not (abs(px) <= MAX_COORD_M and abs(py) <= MAX_COORD_M and abs(pz) <= MAX_COORD_M):
            raise OutOfRangeError(
                f"{key}[{i}] position outside +-{MAX_COORD_M} m or not finite", field=f"{key}[{i}]"
            )
        n2 = qx * qx + qy * qy + qz * qz + qw * qw
        if not _NORM2_LO <= n2 <= _NORM2_HI:  # NaN fails too
            if not all(math.isfinite(v) for v in (qx, qy, qz, qw)):
                raise OutOfRangeError(f"{key}[{i}] orientation not finite", field=f"{key}[{i}]")
            raise NotNormalisedError(
                f"{key}[{i}] orientation has norm {math.sqrt(n2):.6f}", field=f"{key}[{i}]"
            )
        n = math.sqrt(n2)
        out.append((px, py, pz, qx / n, qy / n, qz / n, qw / n))
    a = np.array(out, dtype=np.float64)  # (n, 7)
    return a[:, :3].copy(), a[:, 3:].copy()


def as_sites(m: Map, key: str, valid: int | None) -> tuple[F64, F64, int]:
    """A tracker set's rows (:func:`site_rows`), checked as :func:`as_trackers` checks
    trackers, with ``valid`` (``None``: all) a bit mask over them. Returns
    ``(xyz (n, 3), quat (n, 4), valid)``."""
    rows = _get(m, key, "")
    if type(rows) is not list or not 1 <= len(rows) <= NUM_SITES:
        raise _bad(key, f"an array of 1 to {NUM_SITES} sites")
    full = (1 << len(rows)) - 1
    if valid is None:
        valid = full
    elif valid > full:
        raise OutOfRangeError(f"valid {valid} has bits beyond the {len(rows)} sites", field="valid")
    pos, quat = _tracker_rows(rows, key, valid)
    return pos, quat, valid
