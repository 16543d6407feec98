"""The msgpack writer and case builders behind ``generate.py`` (see its docstring)."""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, replace
from typing import Any

import msgpack

from posecast.errors import ProtocolError
from posecast.online.protocol import codec
from posecast.online.protocol import messages as m
from posecast.online.protocol.wire import FIELD_ORDER, FIELD_ORDER_V1


class Raw(bytes):
    """Bytes the writer copies verbatim (an ext, bad UTF-8, a lying header)."""


@dataclass(frozen=True)
class Style:
    float32: bool = False  # floats as msgpack float32
    int_floats: bool = False  # integral floats as ints (what JavaScript encoders do)
    wide_ints: bool = False  # every int as uint64 / int64
    wide_headers: bool = False  # str16, bin16, array16, map16 instead of the smallest
    reverse_keys: bool = False  # every map's keys in reverse order


def pack(v: Any, s: Style = Style()) -> bytes:
    """A msgpack writer with knobs; ``Style()`` matches the canonical packer."""
    if isinstance(v, Raw):
        return bytes(v)
    if v is None or isinstance(v, bool):
        return {None: b"\xc0", False: b"\xc2", True: b"\xc3"}[v]
    if isinstance(v, int):
        if s.wide_ints:
            return b"\xcf" + struct.pack(">Q", v) if v >= 0 else b"\xd3" + struct.pack(">q", v)
        return bytes(msgpack.packb(v))
    if isinstance(v, float):
        if s.int_floats and v.is_integer() and abs(v) < 2**63:
            return pack(int(v), replace(s, int_floats=False))
        return b"\xca" + struct.pack(">f", v) if s.float32 else b"\xcb" + struct.pack(">d", v)
    if isinstance(v, str):
        b = v.encode()
        return b"\xda" + struct.pack(">H", len(b)) + b if s.wide_headers else msgpack.packb(v)
    if isinstance(v, bytes):
        if s.wide_headers:
            return b"\xc5" + struct.pack(">H", len(v)) + v
        return bytes(msgpack.packb(v, use_bin_type=True))
    if isinstance(v, list):
        head = b"\xdc" + struct.pack(">H", len(v)) if s.wide_headers else _head(len(v), 0x90)
        return head + b"".join(pack(x, s) for x in v)
    if isinstance(v, dict):
        items = list(v.items())[:: -1 if s.reverse_keys else 1]
        head = b"\xde" + struct.pack(">H", len(v)) if s.wide_headers else _head(len(v), 0x80)
        return head + b"".join(pack(k, s) + pack(x, s) for k, x in items)
    raise TypeError(type(v))


def _head(n: int, fix: int) -> bytes:
    if n < 16:
        return bytes([fix + n])
    return (b"\xdc" if fix == 0x90 else b"\xde") + struct.pack(">H", n)


def _floats(v: Any) -> list[float]:
    if isinstance(v, float):
        return [v]
    if isinstance(v, list):
        return [f for x in v for f in _floats(x)]
    if isinstance(v, dict):
        return [f for x in v.values() for f in _floats(x)]
    return []


def _f32_exact(x: float) -> bool:
    return float(struct.unpack(">f", struct.pack(">f", x))[0]) == x


def variants(wire: dict[str, Any], version: int = 1) -> list[bytes]:
    """Other encodings of ``wire`` that every decoder must accept as the same message."""
    floats = _floats(wire)
    styles = [Style(reverse_keys=True), Style(wide_ints=True), Style(wide_headers=True)]
    if floats and all(_f32_exact(f) for f in floats):
        styles.append(Style(float32=True))
    if any(f.is_integer() for f in floats):
        styles.append(Style(int_floats=True))
    out = [pack(wire, s) for s in styles]
    order = FIELD_ORDER if version >= 2 else FIELD_ORDER_V1
    absent = [k for k in order[wire["type"]] if k not in wire]
    if absent:  # nil is the same as absent
        out.append(pack({**wire, **dict.fromkeys(absent)}))
    out.append(pack({**wire, "x_future": {"note": "ignored", "list": [1, 2.5, None]}}))
    return out


def to_json(v: Any) -> Any:
    """Wire value -> JSON: bins become ``{"$bin": hex}``, the rest is unchanged."""
    if isinstance(v, bytes):
        return {"$bin": v.hex()}
    if isinstance(v, list):
        return [to_json(x) for x in v]
    if isinstance(v, dict):
        return {k: to_json(x) for k, x in v.items()}
    return v


def valid(
    name: str,
    msg: m.Message,
    description: str,
    extra: tuple[bytes, ...] = (),
    version: int = 1,
) -> dict[str, Any]:
    """A valid case written for protocol ``version``; it lists every version it holds in."""
    wire = codec.to_wire(msg)
    canonical = codec.encode(msg)
    assert canonical == pack(wire), name  # the canonical packer == msgpack-python's
    alts: list[str] = []
    for b in [*extra, *variants(wire, version)]:
        if b != canonical and b.hex() not in alts:
            assert codec.encode(codec.decode(b, version=version)) == canonical, name
            alts.append(b.hex())
    assert codec.encode(codec.decode(canonical, version=version)) == canonical, name
    return {
        "name": name,
        "description": description,
        "versions": [v for v in m.VERSIONS if v == version or _holds(canonical, alts, v)],
        "message": to_json(wire),
        "canonical_hex": canonical.hex(),
        "also_accept_hex": alts,
    }


def _holds(canonical: bytes, alts: list[str], version: int) -> bool:
    """Whether a valid case written for one version is just as valid in ``version``."""
    try:
        for b in [canonical, *map(bytes.fromhex, alts)]:
            if codec.encode(codec.decode(b, version=version)) != canonical:
                return False
    except ProtocolError:
        return False
    return True


def _fails(b: bytes, version: int) -> tuple[str, str | None] | None:
    try:
        codec.decode(b, version=version)
    except ProtocolError as exc:
        return exc.code, exc.field
    return None


def invalid(
    name: str,
    data: bytes | dict[str, Any],
    error: str,
    description: str,
    field: str | None = None,
    version: int = 1,
) -> dict[str, Any]:
    """An invalid case written for ``version``; it lists every version that refuses it
    with the same code and field."""
    b = data if isinstance(data, bytes) else pack(data)
    got = _fails(b, version)
    assert got == (error, field), (name, got)
    versions = [v for v in m.VERSIONS if v == version or _fails(b, v) == (error, field)]
    case = {"name": name, "description": description, "versions": versions, "hex": b.hex(),
            "error": error}  # fmt: skip
    if field is not None:
        case["field"] = field
    return case


def render(cases: list[dict[str, Any]]) -> str:
    """JSON with one case field per line and arrays of scalars kept on one line."""
    return _dump(cases, 0) + "\n"


def _dump(v: Any, level: int) -> str:
    pad, inner = " " * level, " " * (level + 1)
    if isinstance(v, list) and v and any(isinstance(x, (list, dict)) for x in v):
        return "[\n" + ",\n".join(inner + _dump(x, level + 1) for x in v) + "\n" + pad + "]"
    if isinstance(v, dict) and v:
        body = ",\n".join(f"{inner}{json.dumps(k)}: {_dump(x, level + 1)}" for k, x in v.items())
        return "{\n" + body + "\n" + pad + "}"
    return json.dumps(v, ensure_ascii=False)
