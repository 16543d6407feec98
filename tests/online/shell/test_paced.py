"""Read budgets (posecast.online.shell.paced): the frame-header scanner and the budgets,
pure; the connection that uses them is tested on a real server in
tests/system/test_transport_edge.py."""

from __future__ import annotations

import struct

import pytest

from posecast.online.shell.paced import (
    CONTROL_FRAMES_BURST,
    PRE_HELLO_FRAMES_BURST,
    RESUME_S,
    Budget,
    Budgets,
    FrameScanner,
    ReadBudget,
)


def frame(opcode: int, payload: bytes, *, fin: bool = True, masked: bool = True) -> bytes:
    n = len(payload)
    b0 = (0x80 if fin else 0) | opcode
    m = 0x80 if masked else 0
    if n < 126:
        head = bytes((b0, m | n))
    elif n < 65536:
        head = bytes((b0, m | 126)) + struct.pack("!H", n)
    else:
        head = bytes((b0, m | 127)) + struct.pack("!Q", n)
    return head + (b"\0\0\0\0" if masked else b"") + payload


BIG = 10**9


def test_whole_frames_of_every_length_form_pass_when_the_budget_allows() -> None:
    data = frame(0x2, b"a" * 5) + frame(0x2, b"b" * 300) + frame(0x2, b"c" * 70_000)
    data += frame(0x9, b"") + frame(0x0, b"x", fin=False)
    assert FrameScanner().scan(data, BIG, BIG, BIG) == (len(data), 5, 1, None)


def test_the_scan_stops_at_the_frame_budget_before_a_header() -> None:
    one = frame(0x2, b"x" * 10)
    assert FrameScanner().scan(one * 5, 3, BIG, BIG) == (3 * len(one), 3, 0, "frames")


def test_control_frames_have_their_own_budget() -> None:
    data = frame(0x9, b"") * 3 + frame(0x2, b"m") + frame(0xA, b"")
    end, frames, control, limited = FrameScanner().scan(data, BIG, 2, BIG)
    assert (end, frames, control, limited) == (12, 2, 2, "control")


def test_payload_bytes_pass_up_to_the_byte_budget_and_the_rest_later() -> None:
    data = frame(0x2, b"x" * 1000)
    sc = FrameScanner()
    end, frames, _, limited = sc.scan(data, BIG, BIG, 100)
    assert (end, frames, limited) == (100, 1, "bytes")
    assert sc.left == 1000 - (100 - 8)
    end2, frames2, _, limited2 = sc.scan(data[end:], BIG, BIG, BIG)
    assert (end2, frames2, limited2) == (len(data) - 100, 0, None)  # the same frame
    assert sc.left == 0


def test_a_header_split_between_reads_waits_for_its_bytes() -> None:
    data = frame(0x2, b"y" * 300) + frame(0x9, b"")
    sc = FrameScanner()
    for cut in range(1, 8):  # inside the first header (2 + 2 + 4 bytes)
        sc.left = 0
        assert sc.scan(data[:cut], BIG, BIG, BIG) == (0, 0, 0, None)
    end, frames, _, _ = sc.scan(data, BIG, BIG, BIG)
    assert (end, frames) == (len(data), 2)


def test_a_header_never_passes_in_part_for_the_byte_budget() -> None:
    data = frame(0x2, b"z" * 200)  # 2 + 2 + 4 header bytes
    assert FrameScanner().scan(data, BIG, BIG, 5) == (0, 0, 0, "bytes")


@pytest.mark.parametrize("n", [0, 1, 125, 126, 65535, 65536])
def test_lengths_at_the_edges_of_each_form(n: int) -> None:
    data = frame(0x2, b"q" * n) * 2
    assert FrameScanner().scan(data, BIG, BIG, BIG) == (len(data), 2, 0, None)


def test_unmasked_frames_are_walked_too() -> None:
    """A client must mask (websockets then refuses the frame); the scanner only counts."""
    data = frame(0x2, b"u" * 30, masked=False) * 3
    assert FrameScanner().scan(data, BIG, BIG, BIG) == (len(data), 3, 0, None)


def test_the_budget_refills_at_its_rates_and_says_how_long_to_wait() -> None:
    b = ReadBudget(Budget(10.0, 5.0, 1000.0, 500.0), now=0.0)
    assert b.allowance(0.0) == (5, CONTROL_FRAMES_BURST, 500)
    b.spend(0.0, 5, 0, 500)
    assert b.allowance(0.0) == (0, CONTROL_FRAMES_BURST, 0)
    assert b.wait_s("frames") == pytest.approx(max(1.0, 10.0 * RESUME_S) / 10.0)
    assert b.allowance(0.3) == (3, CONTROL_FRAMES_BURST, 300)


def test_before_hello_a_few_frames_then_twice_the_protocol() -> None:
    b = Budgets.for_limits(
        max_rate_hz=120, rate_burst=30, control_rate_hz=20, max_frame_bytes=65536,
        max_message_bytes=8192,
    )  # fmt: skip
    assert b.before_hello.frames_burst == PRE_HELLO_FRAMES_BURST
    assert b.before_hello.bytes_burst == 65536  # the largest frame passes at once
    assert b.joined.frames_hz == 2 * (120 + 20)
    assert b.joined.frames_burst == 2 * (30 + 20)


def test_a_raised_budget_keeps_what_was_saved_not_a_full_burst() -> None:
    """A hundred flooders admitted together must not each be handed the joined burst
    (100 frames) at once: the joined budget starts from the tokens saved before."""
    before = ReadBudget(Budget(4.0, 8.0, 1000.0, 1000.0), now=0.0)
    before.spend(0.0, 6, 2, 900)
    up = before.raised(Budget(280.0, 100.0, 1e6, 1e5), now=0.0)
    assert up.allowance(0.0) == (2, CONTROL_FRAMES_BURST - 2, 100)
    assert up.allowance(0.1) == (30, CONTROL_FRAMES_BURST - 2, 100_000)  # its rates, its burst
