"""The shell frames outgoing messages itself: byte for byte what websockets writes."""

from __future__ import annotations

from websockets.frames import Frame, Opcode
from websockets.protocol import Protocol, Side, State
from websockets.streams import StreamReader

from posecast.online.shell.app import binary_frames

SIZES = (0, 1, 125, 126, 127, 300, 65535, 65536, 70000)


def _websockets_bytes(batch: list[bytes]) -> bytes:
    proto = Protocol(Side.SERVER, state=State.OPEN, max_size=None)
    for data in batch:
        proto.send_binary(data)
    return b"".join(proto.data_to_send())


def test_each_length_class_frames_as_websockets_does() -> None:
    for n in SIZES:
        data = bytes(range(256)) * (n // 256) + bytes(n % 256)
        assert binary_frames([data]) == _websockets_bytes([data]), n


def test_a_batch_is_the_frames_back_to_back_and_parses_as_messages() -> None:
    batch = [bytes([i % 251]) * n for i, n in enumerate(SIZES)]
    wire = binary_frames(batch)
    assert wire == _websockets_bytes(batch)
    reader = StreamReader()
    reader.feed_data(wire)
    reader.feed_eof()
    parser = Frame.parse(reader.read_exact, mask=False, max_size=None)
    got = []
    for _ in batch:
        try:
            next(parser)
        except StopIteration as done:
            frame = done.value
        assert frame.fin and frame.opcode is Opcode.BINARY
        got.append(bytes(frame.data))
        parser = Frame.parse(reader.read_exact, mask=False, max_size=None)
    assert got == batch
    assert binary_frames([]) == b""
