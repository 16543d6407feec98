"""The bus wire format (posecast.online.cluster.bus): messages round trip, unknown
versions and kinds are skipped."""

from __future__ import annotations

from posecast.online.cluster.bus import BusMessage, decode_message, encode_message


def test_bus_messages_round_trip_and_unknown_ones_are_skipped() -> None:
    for m in (
        BusMessage("tick", "n1", poses=(("a", b"\x01\x02"),), events=(b"ev",)),
        BusMessage("tick", "n1"),
        BusMessage("join", "n1", "a", "Ann"),
        BusMessage("leave", "n2", "a"),
    ):
        assert decode_message(encode_message(m)) == m
    newer = encode_message(BusMessage("join", "n1", "a", "A")).replace(b"\xa1v\x01", b"\xa1v\x02")
    assert decode_message(newer) is None  # a newer node's message: skipped, not fatal
    assert decode_message(b"\xc1garbage") is None


def test_a_malformed_bus_message_is_skipped_not_raised_nor_allocated() -> None:
    """What another node (or anything that can publish on the bus) sends is checked:
    an infinite burn expiry once raised OverflowError out of the listener, a pose
    given as an integer made ``bytes(n)`` allocate n zero bytes, and an event that was
    not bytes went into client outboxes as it was."""
    import msgpack

    def pack(body: dict[str, object]) -> bytes:
        out: bytes = msgpack.packb({"v": 1, "n": "other", **body}, use_bin_type=True)
        return out

    for body in (
        {"k": "burn", "p": "jti", "x": float("inf")},
        {"k": "burn", "p": "jti", "x": 1.5},
        {"k": "tick", "p": [["a", 200_000_000]]},
        {"k": "tick", "p": [["a", "text"]]},
        {"k": "tick", "p": [], "e": ["text"]},
        {"k": "tick", "p": [], "e": [7]},
        {"k": "tick", "p": [], "e": "not a list"},
        {"k": "tick", "p": [["a"]]},
    ):
        assert decode_message(pack(body)) is None, body
    ok = decode_message(pack({"k": "tick", "p": [["a", b"\x81"]], "e": [b"\x80"]}))
    assert ok is not None and ok.poses == (("a", b"\x81"),) and ok.events == (b"\x80",)
