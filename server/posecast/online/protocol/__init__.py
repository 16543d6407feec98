"""Wire protocols v1 and v2: typed messages and their canonical msgpack bytes (no I/O).

The spec lives in ``proto/README.md`` with language-neutral test vectors in
``proto/vectors/``; this package is its Python implementation::

    from posecast.online.protocol import decode, encode
    msg = decode(data)            # bytes -> Hello | Frame | ... (or ProtocolError)
    data = encode(Ping(t0=1.5))   # message -> canonical bytes
"""

from posecast.online.protocol.codec import decode, encode, from_wire, to_wire
from posecast.online.protocol.messages import (
    DEFAULT_LIMITS,
    MESSAGE_TYPES,
    PROTOCOL_V2,
    PROTOCOL_VERSION,
    ROLE_MAY_SEND,
    ROLE_MAY_SEND_V2,
    SERVER_SENDS,
    SERVER_SENDS_V2,
    SUBPROTOCOL,
    SUBPROTOCOL_V2,
    SUBPROTOCOLS,
    Bye,
    Calibrate,
    Error,
    Frame,
    Hello,
    Kick,
    Limits,
    Member,
    Message,
    Ping,
    Pong,
    Pose,
    PoseRate,
    Poses,
    Presence,
    Resync,
    Selector,
    Skeleton,
    Welcome,
    seq_delta,
    seq_next,
)

__all__ = [
    "DEFAULT_LIMITS",
    "MESSAGE_TYPES",
    "PROTOCOL_V2",
    "PROTOCOL_VERSION",
    "ROLE_MAY_SEND",
    "ROLE_MAY_SEND_V2",
    "SERVER_SENDS",
    "SERVER_SENDS_V2",
    "SUBPROTOCOL",
    "SUBPROTOCOLS",
    "SUBPROTOCOL_V2",
    "Bye",
    "Calibrate",
    "Error",
    "Frame",
    "Hello",
    "Kick",
    "Limits",
    "Member",
    "Message",
    "Ping",
    "Pong",
    "Pose",
    "PoseRate",
    "Poses",
    "Presence",
    "Resync",
    "Selector",
    "Skeleton",
    "Welcome",
    "decode",
    "encode",
    "from_wire",
    "seq_delta",
    "seq_next",
    "to_wire",
]
