"""Bytes <-> messages for protocols v1 and v2. Pure functions: no sockets, no clocks, no state.

This is an implementation of ``proto/README.md`` written apart from the server's;
the shared vectors in ``proto/vectors/`` keep the two honest.

:func:`encode` writes the canonical bytes: a msgpack map with ``type`` first and then
the fields in spec order (:data:`FIELDS`), absent optionals left out, floats as
float64 and everything else in its smallest msgpack form, which is what
``msgpack.packb(..., use_bin_type=True)`` writes for that map.

:func:`decode` accepts any valid encoding and reports the first rule broken, in the
spec's order: size (TOO_LARGE), one msgpack value within the structural bounds
(MALFORMED / TOO_LARGE), a root map, depth and string keys (MALFORMED), ``type``
(BAD_FIELD / UNKNOWN_TYPE), then the fields of that type.

``version`` is the connection's protocol (the subprotocol the server selected): v2
knows ``poses``, ``skeleton``, ``pose_rate``, ``forecast`` and ``resync`` but no
``pose``, wants ``version`` 2 in ``hello``, a ``handle`` (the avatar id,
``avatar_id`` in the message classes) and ``skeleton`` for every ``welcome`` member
and ``presence`` join, and lets a server message and its bins reach 16384 bytes.
``poses.data`` is opaque here: :mod:`posecast_client.records` reads it.

This module is the codec's face: the top-level checks and the canonical key order
(:data:`FIELDS`). The parts, each pure::

    fields.py    one value -> a checked value (the as_* validators)
    wire.py      per message type: checked map -> message, message -> wire values
    quantize.py  pose positions and rotations <-> int16 bytes
"""

from __future__ import annotations

import msgpack

from posecast_client.errors import (
    BadFieldError,
    MalformedError,
    TooLargeError,
    UnknownTypeError,
)
from posecast_client.fields import ID_PATTERN, SKELETON_BYTES, Fields, Map, T
from posecast_client.protocol import (
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
from posecast_client.quantize import POS_BYTES, ROT_BYTES, pos2mm, quat2snorm
from posecast_client.wire import DECODERS, ENCODERS

__all__ = [
    "FIELDS",
    "ID_PATTERN",
    "POS_BYTES",
    "ROT_BYTES",
    "SKELETON_BYTES",
    "V1_TYPES",
    "V2_TYPES",
    "Map",
    "T",
    "decode",
    "encode",
    "pos2mm",
    "quat2snorm",
    "to_wire",
]

# Canonical key order of every message (after "type"): the spec's field tables.
FIELDS: dict[str, tuple[str, ...]] = {
    "hello": ("version", "token", "room", "name", "layout", "rate_hz", "watch", "pose_rate_hz",
              "forecast_ms"),
    "welcome": ("version", "player", "session", "role", "room", "t", "rate_hz",
                "lookahead_frames", "members", "limits", "pose_rate_hz", "forecast_ms"),
    "calibrate": ("height_m", "tpose", "trackers", "sites"),
    "frame": ("seq", "t", "trackers", "sites", "valid"),
    "pose": ("player", "seq", "t", "root", "pos_mm", "rot"),
    "presence": ("event", "room", "player", "name", "handle", "skeleton"),
    "selector": ("player", "kind", "joint", "point", "radius_m", "margin_m", "factor"),
    "kick": ("player", "reason"),
    "ping": ("t0",),
    "pong": ("t0", "t1", "t2"),
    "error": ("code", "message", "fatal", "field", "ref_seq"),
    "bye": ("reason",),
    "poses": ("t", "data"),
    "skeleton": ("player", "handle", "skeleton"),
    "pose_rate": ("rate_hz",),
    "resync": (),
    "forecast": ("ms",),
}  # fmt: skip
V1_TYPES = frozenset(FIELDS) - {"poses", "skeleton", "pose_rate", "resync", "forecast"}
V2_TYPES = frozenset(FIELDS) - {"pose"}
_V2_CLIENT_TYPES = frozenset().union(*ROLE_MAY_SEND_V2.values())
_LEAVES = (type(None), bool, int, float, str, bytes)


# --- decoding ------------------------------------------------------------------------


def decode(
    data: bytes,
    *,
    limits: Limits = DEFAULT_LIMITS,
    max_bytes: int | None = None,
    version: int = PROTOCOL_VERSION,
) -> Message:
    """Parse and validate one WebSocket message.

    Args:
        data: one whole binary WebSocket message.
        limits: the limits in force; the defaults are the v1 maxima.
        max_bytes: a tighter size cap than the version's bound, if given.
        version: the connection's protocol, 1 or 2.

    Raises:
        ProtocolError: the subclass of the first rule broken, with ``field`` set where
            the spec names one (and ``ref_seq`` for a frame whose ``seq`` was read).
    """
    v2 = version >= PROTOCOL_V2
    top = MAX_SERVER_MESSAGE_BYTES_V2 if v2 else limits.max_message_bytes
    cap = top if max_bytes is None else min(max_bytes, top)
    if len(data) > cap:
        raise TooLargeError(f"message of {len(data)} bytes, limit {cap}")
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,  # str must be UTF-8
            strict_map_key=True,  # str (or bin, refused below) keys only
            max_str_len=MAX_STR_BYTES,  # the bounds are checked at each header,
            max_bin_len=cap if v2 else MAX_BIN_BYTES,  # before anything is allocated
            max_array_len=MAX_ARRAY_LEN,
            max_map_len=MAX_MAP_LEN,
        )
    except ValueError as exc:  # ExtraData, FormatError, StackError, UnicodeDecodeError...
        if "exceeds max_" in str(exc):
            raise TooLargeError(f"msgpack: {exc}") from None
        raise MalformedError(f"not one msgpack value: {type(exc).__name__}") from None
    if type(obj) is not dict:
        raise MalformedError("a message is a msgpack map")
    _check_structure(obj, 1)
    kind = obj.get("type")
    if type(kind) is not str:
        raise BadFieldError("type is missing or not a string", field="type")
    read = DECODERS.get(kind)
    if read is None or kind not in (V2_TYPES if v2 else V1_TYPES):
        raise UnknownTypeError(f"unknown message type {kind[:40]!r}", field="type")
    if v2 and kind in _V2_CLIENT_TYPES and len(data) > limits.max_message_bytes:
        raise TooLargeError(f"a {kind} message of {len(data)} bytes")
    return read(Fields(obj, version=version), limits)


def _check_structure(value: object, depth: int) -> None:
    """MALFORMED for nesting deeper than MAX_DEPTH, a non-str key or an ext value."""
    if type(value) is dict:
        if depth > MAX_DEPTH:
            raise MalformedError(f"nested deeper than {MAX_DEPTH}")
        for key, item in value.items():
            if type(key) is not str:
                raise MalformedError("map keys must be strings")
            _check_structure(item, depth + 1)
    elif type(value) is list:
        if depth > MAX_DEPTH:
            raise MalformedError(f"nested deeper than {MAX_DEPTH}")
        for item in value:
            _check_structure(item, depth + 1)
    elif type(value) not in _LEAVES:  # ExtType, Timestamp
        raise MalformedError("msgpack ext types are not used in v1")


# --- encoding ------------------------------------------------------------------------


def encode(msg: Message) -> bytes:
    """The canonical msgpack bytes of ``msg``.

    The message is trusted (build frames with
    :meth:`posecast_client.session.ClientSession.frame`, which checks them), except
    where quantising needs it: a pose joint more than 32.767 m from its pelvis is
    OUT_OF_RANGE, a rotation far from unit length NOT_NORMALISED.
    """
    out: bytes = msgpack.packb(to_wire(msg), use_bin_type=True)
    return out


def to_wire(msg: Message) -> Map:
    """The canonical wire map of ``msg``: keys in spec order, absent optionals left out."""
    values = ENCODERS[msg.TYPE](msg)
    return {
        "type": msg.TYPE,
        **{k: values[k] for k in FIELDS[msg.TYPE] if values.get(k) is not None},
    }
