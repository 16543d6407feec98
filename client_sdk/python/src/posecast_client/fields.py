"""Field validators for the decoder: one msgpack value in, a checked Python value out.

Each ``as_*`` takes the value, its path (``trackers[2]``, ``limits.max_players``)
and the bounds, and raises the :class:`~posecast_client.errors.ProtocolError` the
spec names: BAD_FIELD for a wrong type, shape or value, OUT_OF_RANGE for a number
outside its range (NaN included) or a string of the wrong length, NOT_NORMALISED
for a quaternion off unit length. :class:`Fields` reads one map with them: a nil
value is the same as an absent field. Pure, like the rest of the codec; the server's
twin is ``posecast.online.protocol.fields``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from posecast_client.errors import BadFieldError, NotNormalisedError, OutOfRangeError
from posecast_client.protocol import (
    F64,
    LAYOUTS,
    LIMIT_RANGES,
    MAX_COORD_M,
    MAX_FORECAST_MS,
    MAX_ID_BYTES,
    MAX_LAYOUT_BYTES,
    MAX_TIME_S,
    POSE_RATES_HZ,
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    QUAT_TOLERANCE,
    UINT32_MAX,
    Limits,
    Member,
)
from posecast_client.sites import MAX_SITES, tracker_set

Map = dict[str, Any]
T = TypeVar("T")

ID_PATTERN = re.compile(r"[A-Za-z0-9_.:-]+")  # rooms, player and session ids
CODE_PATTERN = re.compile(r"[A-Z][A-Z0-9_]{0,31}")  # error codes
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")  # not allowed in display names
SKELETON_BYTES = 108  # a v2 skeleton: 18 x 3 int16


class Fields:
    """The fields of one map; ``at`` prefixes paths in nested maps (``limits.``)."""

    def __init__(self, m: Map, at: str = "", version: int = PROTOCOL_VERSION) -> None:
        self.m, self.at, self.version = m, at, version

    def has(self, key: str) -> bool:
        return self.m.get(key) is not None  # nil means absent

    def req(self, key: str, check: Callable[..., T], *args: Any) -> T:
        v = self.m.get(key)
        if v is None:
            raise BadFieldError(f"missing field {self.at}{key}", field=self.at + key)
        return check(v, self.at + key, *args)

    def opt(self, key: str, check: Callable[..., T], *args: Any) -> T | None:
        v = self.m.get(key)
        return None if v is None else check(v, self.at + key, *args)


def bad(path: str, expected: str) -> BadFieldError:
    return BadFieldError(f"{path}: expected {expected}", field=path)


def as_int(v: Any, path: str, lo: int, hi: int) -> int:
    if type(v) is not int:  # bool is not an int here, and 7.0 is not either
        raise bad(path, "an integer")
    if not lo <= v <= hi:
        raise OutOfRangeError(f"{path}={v} outside [{lo}, {hi}]", field=path)
    return v


def as_float(v: Any, path: str, lo: float, hi: float) -> float:
    if type(v) is not float and type(v) is not int:
        raise bad(path, "a number")
    f = float(v)
    if not lo <= f <= hi:  # NaN fails too
        raise OutOfRangeError(f"{path}={f} outside [{lo}, {hi}]", field=path)
    return f


def as_time(v: Any, path: str) -> float:
    return as_float(v, path, 0.0, MAX_TIME_S)


def as_bool(v: Any, path: str) -> bool:
    if type(v) is not bool:
        raise bad(path, "a boolean")
    return v


def as_str(v: Any, path: str, lo: int, hi: int) -> str:
    if type(v) is not str:
        raise bad(path, "a string")
    n = len(v.encode())
    if not lo <= n <= hi:
        raise OutOfRangeError(f"{path} is {n} bytes, not {lo}..{hi}", field=path)
    return v


def as_id(v: Any, path: str, hi: int = MAX_ID_BYTES) -> str:
    s = as_str(v, path, 1, hi)
    if ID_PATTERN.fullmatch(s) is None:
        raise bad(path, "only A-Z a-z 0-9 _ . : -")
    return s


def as_name(v: Any, path: str, hi: int) -> str:
    s = as_str(v, path, 1, hi)
    if _CONTROL.search(s) is not None:
        raise bad(path, "no control characters")
    return s


def as_enum(v: Any, path: str, options: tuple[str, ...]) -> str:
    if type(v) is not str or v not in options:
        raise bad(path, "one of " + ", ".join(options))
    return v


def as_array(v: Any, path: str, max_len: int) -> list[Any]:
    if type(v) is not list:
        raise bad(path, "an array")
    if len(v) > max_len:
        raise OutOfRangeError(f"{path} has {len(v)} items, at most {max_len}", field=path)
    return v


def as_bin(v: Any, path: str, size: int) -> bytes:
    if type(v) is not bytes or len(v) != size:
        raise bad(path, f"a bin of {size} bytes")
    return v


def as_numbers(v: Any, path: str, n: int) -> list[float]:
    if type(v) is not list or len(v) != n or any(type(x) not in (int, float) for x in v):
        raise bad(path, f"an array of {n} numbers")
    return [float(x) for x in v]


def as_point(v: Any, path: str) -> tuple[float, float, float]:
    x, y, z = as_numbers(v, path, 3)
    if not (abs(x) <= MAX_COORD_M and abs(y) <= MAX_COORD_M and abs(z) <= MAX_COORD_M):
        raise OutOfRangeError(f"{path} not finite or beyond {MAX_COORD_M} m", field=path)
    return x, y, z


def as_layout(v: Any, path: str) -> str:
    """``hello.layout``: a named layout or a tracker set (:mod:`posecast_client.sites`)."""
    text = as_str(v, path, 1, MAX_LAYOUT_BYTES)
    if text not in LAYOUTS:
        try:
            tracker_set(text)
        except ValueError as exc:
            raise BadFieldError(
                f"layout {text!r}: {exc} (a named layout: {', '.join(LAYOUTS)}, or a tracker set)",
                field=path,
            ) from None
    return text


def as_trackers(v: Any, path: str, valid: int) -> tuple[F64, F64]:
    """4 rows ``[px py pz qx qy qz qw]`` -> positions (4, 3), orientations (4, 4).

    Tracked slots are range-checked and their quaternions renormalised exactly as the
    spec writes it; untracked slots are only type-checked and read as origin + identity.
    """
    if type(v) is not list or len(v) != 4:
        raise bad(path, "an array of 4 trackers")
    return _checked_rows(v, path, valid)


def as_sites(v: Any, path: str, valid: int | None) -> tuple[F64, F64, int]:
    """A tracker set's 1 to 10 rows, checked as :func:`as_trackers` checks trackers, with
    ``valid`` (``None``: all) a bit mask over them -> ``(positions, orientations, valid)``."""
    if type(v) is not list or not 1 <= len(v) <= MAX_SITES:
        raise bad(path, f"an array of 1 to {MAX_SITES} sites")
    full = (1 << len(v)) - 1
    if valid is not None and valid > full:
        raise OutOfRangeError(f"valid {valid} has bits beyond the {len(v)} sites", field="valid")
    mask = full if valid is None else valid
    return (*_checked_rows(v, path, mask), mask)


def _checked_rows(v: list[Any], path: str, valid: int) -> tuple[F64, F64]:
    out = np.zeros((len(v), 7))  # (n, 7)
    out[:, 6] = 1.0
    for i, row in enumerate(v):
        at = f"{path}[{i}]"
        px, py, pz, qx, qy, qz, qw = as_numbers(row, at, 7)
        if not valid >> i & 1:
            continue
        if not (abs(px) <= MAX_COORD_M and abs(py) <= MAX_COORD_M and abs(pz) <= MAX_COORD_M):
            raise OutOfRangeError(f"{at} position not finite or beyond {MAX_COORD_M} m", field=at)
        if not all(map(math.isfinite, (qx, qy, qz, qw))):
            raise OutOfRangeError(f"{at} orientation not finite", field=at)
        n = math.sqrt(((qx * qx + qy * qy) + qz * qz) + qw * qw)
        if not abs(n - 1.0) <= QUAT_TOLERANCE:
            raise NotNormalisedError(f"{at} orientation has norm {n:.6f}", field=at)
        out[i] = (px, py, pz, qx / n, qy / n, qz / n, qw / n)
    return out[:, :3].copy(), out[:, 3:].copy()


def as_members(v: Any, path: str, lim: Limits, version: int) -> tuple[Member, ...]:
    members = []
    for i, item in enumerate(as_array(v, path, lim.max_players)):
        if type(item) is not dict:
            raise bad(f"{path}[{i}]", "a map")
        f = Fields(item, f"{path}[{i}].")
        player, name = f.req("player", as_id), f.req("name", as_name, lim.max_name_bytes)
        if version >= PROTOCOL_V2:
            members.append(Member(player, name, f.req("handle", as_int, 0, UINT32_MAX),
                                  f.req("skeleton", as_bin, SKELETON_BYTES)))  # fmt: skip
        else:
            members.append(Member(player, name))
    return tuple(members)


def as_pose_rate(v: Any, path: str) -> float:
    rate = as_float(v, path, 0.0, 1000.0)
    if rate not in POSE_RATES_HZ:
        raise OutOfRangeError(f"{path}={rate}: not 60, 30, 20 or 15", field=path)
    return rate


def as_forecast(v: Any, path: str) -> float:
    return as_float(v, path, 0.0, MAX_FORECAST_MS)


def as_limits(v: Any, path: str) -> Limits:
    if type(v) is not dict:
        raise bad(path, "a map")
    f = Fields(v, path + ".")
    return Limits(**{k: f.req(k, as_int, lo, hi) for k, (lo, hi) in LIMIT_RANGES.items()})


def as_data(v: Any, path: str) -> bytes:
    if type(v) is not bytes:
        raise bad(path, "a bin")
    return v
