"""The JSON data model of posecast messages: one msgpack message as the JSON value that
``schema.json`` validates (README.md, "The JSON data model").

    >>> render(bytes.fromhex("82a474797065a470696e67a27430cb3ff0000000000000"))
    {'type': 'ping', 't0': 1.0}

=================  ==============================================================
msgpack            JSON
=================  ==============================================================
nil, bool          ``null``, ``true``/``false``
int                a number without a fraction
float              a number, or ``{"$float": "NaN" | "Infinity" | "-Infinity"}``
str                a string
bin                ``{"$bin": "<its bytes in lower-case hex>"}``
array              an array
map                an object, its keys in the order sent
=================  ==============================================================

Some bytes have no rendering, and :func:`render` raises :class:`NotRepresentableError` for
them: bytes that are not exactly one msgpack value (empty, truncated, trailing bytes,
a never-used byte such as ``0xc1``), an ext type (the timestamp included), a str that
is not UTF-8, a map key that is not a str, and more than 64 nested arrays and maps. A
decoder refuses all of these by the rules it applies to the bytes (``MALFORMED``,
``TOO_LARGE``), before any schema. Two more have none though a decoder may accept
them: a map with a key twice (a JSON object's names are unique), and a map whose only
key is ``$bin`` or ``$float`` (it would read as a bin or a float). No vector has either.

Only ``msgpack`` (msgpack-python) is needed: the conformance script uses this module.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack

RESERVED = ("$bin", "$float")  # a map of just one of these keys would read as a bin or a float
MAX_NESTING = 64  # arrays and maps; the spec allows 8, so deeper is MALFORMED anyway


class NotRepresentableError(ValueError):
    """Bytes that no JSON value renders (why is the message)."""


def render(data: bytes) -> Any:
    """The JSON rendering of one msgpack message."""
    try:
        value = msgpack.unpackb(
            data, raw=False, strict_map_key=False, object_pairs_hook=_Pairs, use_list=True
        )
    except Exception as exc:  # msgpack raises ValueError, its own errors and UnicodeDecodeError
        raise NotRepresentableError(f"not one msgpack value: {type(exc).__name__} {exc}") from None
    return to_json(value)


class _Pairs(list[tuple[Any, Any]]):
    """A map as msgpack-python read it: its pairs in order (duplicates kept, to refuse)."""


def to_json(value: Any, depth: int = 0) -> Any:
    """A decoded msgpack value (maps as :class:`_Pairs`) as JSON, at most
    :data:`MAX_NESTING` containers deep."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if math.isnan(value):
            return {"$float": "NaN"}
        if math.isinf(value):
            return {"$float": "Infinity" if value > 0 else "-Infinity"}
        return value
    if isinstance(value, bytes):
        return {"$bin": value.hex()}
    if depth >= MAX_NESTING:
        raise NotRepresentableError(f"more than {MAX_NESTING} nested arrays and maps")
    if isinstance(value, _Pairs):
        out: dict[str, Any] = {}
        for k, v in value:
            if type(k) is not str:
                raise NotRepresentableError(f"a map key that is a {type(k).__name__}, not a str")
            if k in out:
                raise NotRepresentableError(f"the map key {k!r} twice")
            out[k] = to_json(v, depth + 1)
        if len(out) == 1 and next(iter(out)) in RESERVED:
            raise NotRepresentableError(
                f"a map of the one key {next(iter(out))!r}: a bin's or float's form"
            )
        return out
    if isinstance(value, list):
        return [to_json(v, depth + 1) for v in value]
    raise NotRepresentableError(f"an ext type ({type(value).__name__})")
