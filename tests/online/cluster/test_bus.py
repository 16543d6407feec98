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
