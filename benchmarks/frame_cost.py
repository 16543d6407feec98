"""What one WebSocket frame and one byte from a client cost the server's event loop.

The read budgets of ``posecast.online.shell.paced`` (frames and bytes a connection may
have parsed per second, before and after ``hello``) are set from these figures
(docs/reliability.md, "Read budgets"). Each case feeds a burst of client frames to
websockets' server protocol in the OPEN state, as ``ServerConnection.data_received``
does (parse, events, automatic pongs written to a real socket), and divides the time
by the frames and by the bytes:

* ``ping0``: empty ping frames (6 bytes each with the mask): parse + one pong write each
* ``ping125``: 125-byte pings (the largest control frame)
* ``cont1``: 1-byte continuation frames of a message that never ends
* ``bin300``: 300-byte binary messages (about a player's frame)
* ``bin8k``: 8 KiB binary messages (the largest message posecast decodes)

``python benchmarks/frame_cost.py --frames 20000 --repeat 5 [--json F]`` prints
microseconds a frame and nanoseconds a byte, the median of the repeats.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import struct
import time
from collections.abc import Callable

from websockets.protocol import OPEN, SERVER, Protocol


def _frame(fin: bool, opcode: int, payload: bytes) -> bytes:
    """A masked client frame (zero mask key: the server unmasks it all the same)."""
    n = len(payload)
    head = bytes(((0x80 if fin else 0) | opcode,))
    if n < 126:
        head += bytes((0x80 | n,))
    elif n < 65536:
        head += struct.pack("!BH", 0x80 | 126, n)
    else:
        head += struct.pack("!BQ", 0x80 | 127, n)
    return head + b"\0\0\0\0" + payload


CASES: dict[str, Callable[[int], tuple[bytes, bytes]]] = {
    # name -> frames -> (a prefix fed first, the burst of n frames)
    "ping0": lambda n: (b"", _frame(True, 0x9, b"") * n),
    "ping125": lambda n: (b"", _frame(True, 0x9, b"x" * 125) * n),
    "cont1": lambda n: (_frame(False, 0x2, b"x"), _frame(False, 0x0, b"x") * n),
    "bin300": lambda n: (b"", _frame(True, 0x2, b"x" * 300) * n),
    "bin8k": lambda n: (b"", _frame(True, 0x2, b"x" * 8192) * n),
}


def _protocol() -> Protocol:
    return Protocol(SERVER, state=OPEN, max_size=None)  # past the handshake


def run_case(name: str, frames: int, chunk: int = 256 * 1024) -> tuple[float, int]:
    """Seconds to feed ``frames`` frames of ``name`` in 256 KiB reads, and their bytes."""
    prefix, burst = CASES[name](frames)
    proto = _protocol()
    a, b = socket.socketpair()
    a.setblocking(False)
    b.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    a.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 22)
    try:
        if prefix:
            proto.receive_data(prefix)
            proto.events_received()
        got = 0
        t0 = time.perf_counter()
        for i in range(0, len(burst), chunk):
            proto.receive_data(burst[i : i + chunk])
            events = proto.events_received()
            for out in proto.data_to_send():  # one write per pong, as websockets does
                if out:
                    try:
                        a.send(out)
                    except BlockingIOError:
                        _drain(b)
                        a.send(out)
            got += len(events)
            _drain(b)
        dt = time.perf_counter() - t0
        assert got == frames or name == "cont1", (name, got)  # fragments: no event each
        assert proto.state is OPEN, name
        return dt, len(burst)
    finally:
        a.close()
        b.close()


def _drain(sock: socket.socket) -> None:
    sock.setblocking(False)
    try:
        while sock.recv(1 << 20):
            pass
    except BlockingIOError:
        pass


def cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            flags = next(line for line in f if line.startswith("flags")).split()
    except (OSError, StopIteration):
        return platform.machine()
    wanted = ("avx2", "avx512f", "avx512_bf16")
    return ",".join(f for f in wanted if f in flags) or platform.machine()


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=20_000)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--json", default="")
    args = p.parse_args(argv)
    rows = {}
    print(f"cpu: {cpu_flags()}, {os.cpu_count()} cores; {args.frames} frames a case")
    print(f"{'case':8} {'us/frame':>9} {'ns/byte':>8} {'frames/s at 1% of a core':>26}")
    for name in CASES:
        times = []
        size = 0
        for _ in range(args.repeat):
            dt, size = run_case(name, args.frames)
            times.append(dt)
        dt = statistics.median(times)
        us_frame, ns_byte = dt / args.frames * 1e6, dt / size * 1e9
        rows[name] = {"us_per_frame": us_frame, "ns_per_byte": ns_byte, "bytes": size}
        print(f"{name:8} {us_frame:9.2f} {ns_byte:8.2f} {0.01 / (dt / args.frames):26.0f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"cpu": cpu_flags(), "frames": args.frames, "cases": rows}, f, indent=1)


if __name__ == "__main__":
    main()
