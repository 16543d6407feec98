"""Wire protocols v1 and v2: typed messages and their canonical msgpack bytes (no I/O).

The spec lives in ``proto/README.md`` with language-neutral test vectors in
``proto/vectors/``; this package is its Python implementation::

    from posecast.online.protocol import decode, encode
    msg = decode(data)            # bytes -> Hello | Frame | ... (or ProtocolError)
    data = encode(Ping(t0=1.5))   # message -> canonical bytes
"""

from posecast.online.protocol import messages
from posecast.online.protocol.codec import decode, encode, from_wire, to_wire
from posecast.online.protocol.messages import *  # noqa: F403 (the names of messages.__all__)

__all__ = ["decode", "encode", "from_wire", "to_wire"]
__all__ += messages.__all__
