"""Bytes <-> messages for protocols v1 and v2. Pure functions: no sockets, no clocks, no state.

:func:`encode` writes the canonical bytes (``proto/README.md``, "Canonical
encoding"): a msgpack map, ``type`` first and then the fields in spec order, absent
optionals left out, every float as float64, ints, strings, bins, arrays and maps
in their smallest msgpack form, which is what ``msgpack.packb(..., use_bin_type=True)``
produces for the maps :func:`to_wire` builds.

:func:`decode` accepts any valid encoding and checks, in this order: size
(TOO_LARGE), msgpack syntax and the structural bounds (MALFORMED / TOO_LARGE), that
the root is a map, nesting depth and key types (MALFORMED), ``type`` (BAD_FIELD /
UNKNOWN_TYPE), then the fields of that type (:mod:`posecast.online.protocol.wire`).
``version`` picks the connection's protocol (``posecast.v1`` or ``posecast.v2``):
the types it knows, the fields of ``hello``, ``welcome`` and ``presence``, and the
structural bounds (v2 lets a server message, and its bins, reach 16384 bytes; a
message a client sends stays within ``max_message_bytes``).
"""

from __future__ import annotations

from typing import Any, NoReturn

import msgpack

from posecast.errors import (
    BadFieldError,
    MalformedError,
    ProtocolError,
    TooLargeError,
    UnknownTypeError,
)
from posecast.online.protocol.messages import (
    DEFAULT_LIMITS,
    MAX_ARRAY_LEN,
    MAX_BIN_BYTES,
    MAX_DEPTH,
    MAX_MAP_LEN,
    MAX_SERVER_MESSAGE_BYTES_V2,
    MAX_STR_BYTES,
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    ROLE_MAY_SEND_V2,
    Limits,
    Message,
)
from posecast.online.protocol.wire import DECODERS, ENCODERS

Map = dict[str, Any]


def encode(msg: Message) -> bytes:
    """The canonical msgpack bytes of ``msg``.

    The message is trusted (the codec does not re-validate what the program built)
    except where quantising needs it: a pose with a joint more than 32.767 m from its
    pelvis, or a rotation far from unit length, raises :class:`ProtocolError`.
    """
    out: bytes = msgpack.packb(to_wire(msg), use_bin_type=True)
    return out


def to_wire(msg: Message) -> Map:
    """The canonical wire map of ``msg`` (keys in canonical order), before msgpack."""
    return ENCODERS[msg.TYPE](msg)


_CLIENT_TYPES_V2 = frozenset().union(*ROLE_MAY_SEND_V2.values())


def decode(
    data: bytes,
    *,
    max_bytes: int | None = None,
    limits: Limits = DEFAULT_LIMITS,
    version: int = PROTOCOL_VERSION,
) -> Message:
    """Parse and validate one WebSocket message.

    Args:
        data: the whole binary WebSocket message.
        max_bytes: a tighter size cap than ``limits.max_message_bytes``, if given.
        limits: the limits in force (string lengths, rates, ...); defaults to the v1
            maxima, which is what a client should use before its ``welcome``.
        version: the connection's protocol version, 1 or 2.

    Raises:
        ProtocolError: the subclass for the first rule broken, with ``field`` (and
            ``ref_seq`` for a frame whose ``seq`` was readable) set where they apply.
    """
    v2 = version >= PROTOCOL_V2
    top = MAX_SERVER_MESSAGE_BYTES_V2 if v2 else limits.max_message_bytes
    cap = top if max_bytes is None else min(max_bytes, top)
    if len(data) > cap:
        raise TooLargeError(f"message of {len(data)} bytes, limit {cap}")
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,
            strict_map_key=True,
            max_str_len=MAX_STR_BYTES,
            max_bin_len=MAX_SERVER_MESSAGE_BYTES_V2 if v2 else MAX_BIN_BYTES,
            max_array_len=MAX_ARRAY_LEN,
            max_map_len=MAX_MAP_LEN,
            max_ext_len=0,
            ext_hook=_refuse_ext,
        )
    except _ExtRefusedError:
        raise MalformedError("msgpack ext types are not used by posecast v1") from None
    except ValueError as exc:  # includes ExtraData, FormatError, StackError, UnicodeError
        text = str(exc)
        if "exceeds max_" in text and "max_ext_len" not in text:
            raise TooLargeError(f"msgpack: {text}") from None
        raise MalformedError(f"not one msgpack value: {type(exc).__name__}: {text}") from None
    if (
        v2
        and len(data) > limits.max_message_bytes
        and type(obj) is dict
        and obj.get("type") in _CLIENT_TYPES_V2
    ):
        raise TooLargeError(
            f"a {obj['type']} of {len(data)} bytes, limit {limits.max_message_bytes}"
        )
    return from_wire(obj, limits=limits, version=version)


def from_wire(
    obj: object, *, limits: Limits = DEFAULT_LIMITS, version: int = PROTOCOL_VERSION
) -> Message:
    """Validate an unpacked msgpack value into a message (the second half of decode)."""
    if type(obj) is not dict:
        raise MalformedError(f"a message is a msgpack map, not {_kind(obj)}")
    try:
        kind = obj.get("type")
        if type(kind) is not str:
            raise BadFieldError("missing or non-string field type", field="type")
        entry = DECODERS[version].get(kind)
        if entry is None:
            raise UnknownTypeError(f"unknown message type {kind[:40]!r}", field="type")
        known, decoder = entry
        if kind == "welcome" or not known.issuperset(obj):
            # Unknown fields are ignored but held to the bounds; welcome's nested maps
            # may carry unknown keys too. Both are rare, so walk the whole map.
            _check_structure(obj, 1)
        return decoder(obj, limits, version)
    except MalformedError:
        raise
    except ProtocolError:
        # A field check failed first, but the spec checks structure before fields:
        # walk the whole map now (only on this error path) so the code matches.
        _check_structure(obj, 1)
        raise


def _check_structure(value: object, depth: int) -> None:
    """MALFORMED for a map or array nested deeper than MAX_DEPTH or a non-string key."""
    t = type(value)
    if t is dict or t is list:
        if depth > MAX_DEPTH:
            raise MalformedError(f"nested deeper than {MAX_DEPTH} maps and arrays")
        if t is dict:
            for key, item in value.items():  # type: ignore[attr-defined]
                if type(key) is not str:
                    raise MalformedError("map keys must be strings")
                _check_structure(item, depth + 1)
        else:
            for item in value:  # type: ignore[attr-defined]
                _check_structure(item, depth + 1)


_KINDS = {list: "an array", str: "a str", bytes: "a bin", bool: "a bool", int: "an int"}


def _kind(obj: object) -> str:
    return "nil" if obj is None else _KINDS.get(type(obj), "a " + type(obj).__name__)


class _ExtRefusedError(Exception):
    pass


def _refuse_ext(code: int, data: bytes) -> NoReturn:
    raise _ExtRefusedError
