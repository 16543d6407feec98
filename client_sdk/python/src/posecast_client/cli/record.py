"""``posecast-record``: record a room as a spectator, and export players' poses to BVH.

Record (until Ctrl-C, or for ``--seconds``), then optionally export::

    posecast-record --secret $SECRET --room lobby --out lobby.pcrec --seconds 60 --bvh out/

Export an existing recording::

    posecast-record --export lobby.pcrec --bvh out/

The recording format (a msgpack stream) is described in
:mod:`posecast_client.recording`; the BVH files use the canonical 19-joint skeleton,
one per player (``out/<player>.bvh``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
from collections.abc import Sequence
from pathlib import Path

from posecast_client.cli.common import (
    Parser,
    add_server_arguments,
    check_room,
    connect_patiently,
    failure,
    resolve_server,
    stop_on_signals,
    token_for,
    unique_suffix,
    usage_error,
)
from posecast_client.protocol import Error, Pose, Presence, Welcome
from posecast_client.recording import RecordingWriter, export_bvh, open_recording
from posecast_client.session import Reconnecting

P = "posecast-record"  # the program, as its errors name it


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog=P, description=__doc__.splitlines()[0])
    add_server_arguments(p)
    p.add_argument("--room", help="the room to record")
    p.add_argument("--out", type=Path, help="recording file to write (ROOM.pcrec)")
    p.add_argument("--seconds", type=float, help="stop after this long (default: Ctrl-C)")
    p.add_argument("--name", default="recorder", help="spectator display name (recorder)")
    p.add_argument("--bvh", type=Path, help="export each player's poses to DIR/<player>.bvh")
    p.add_argument("--export", type=Path, metavar="FILE", help="only export FILE (no server)")
    return p


async def record(args: argparse.Namespace) -> Path:
    out: Path = args.out or Path(f"{args.room}.pcrec")
    stop = asyncio.Event()
    stop_on_signals(stop)
    token = token_for(args, args.room, f"rec-{unique_suffix()}", role="spectator")
    client = await connect_patiently(args.url, token)
    writer = RecordingWriter(out, url=args.url, room=args.room)
    try:
        welcome = await client.join(args.room, args.name)
        writer.write(welcome)
        print(f"posecast-record: recording {args.room} to {out}", file=sys.stderr)
        timer = asyncio.create_task(asyncio.wait_for(stop.wait(), args.seconds))
        with contextlib.suppress(TimeoutError):
            async for event in client.events(until=timer):
                if isinstance(event, Pose | Presence | Error | Welcome):
                    writer.write(event)
                elif isinstance(event, Reconnecting):
                    print(f"posecast-record: reconnecting ({event.cause!r})", file=sys.stderr)
            await timer
    finally:
        writer.close()
        await client.close()
    print(f"posecast-record: {writer.count} messages in {out}", file=sys.stderr)
    return out


def _check_bvh_dir(bvh: Path) -> None:
    """Refuse, before a recording starts rather than after it ends, a ``--bvh`` that
    cannot become a directory: a file, or a path under one."""
    at = bvh.absolute()
    while not at.exists():
        at = at.parent
    if not at.is_dir():
        usage_error(
            P,
            f"--bvh {bvh}: {at} is a file, not a directory",
            "name a directory for the BVH files (it is made if missing)",
        )


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.bvh is not None:
        _check_bvh_dir(args.bvh)
    if args.export is not None:
        path = args.export
        if args.bvh is None:
            usage_error(P, "--export needs --bvh DIR", "name where the BVH files go")
    else:
        resolve_server(args, P)
        if not args.room:
            usage_error(P, "--room is required to record", "pass the room to listen to")
        check_room(P, "--room", args.room)
        if args.seconds is not None and not 0 < args.seconds < float("inf"):
            usage_error(P, f"--seconds {args.seconds} must be a positive number", "e.g. 60")
        out = args.out or Path(f"{args.room}.pcrec")
        if not out.parent.is_dir():
            usage_error(P, f"--out {out}: no directory {out.parent}", "create it first")
        if out.is_dir():
            usage_error(
                P, f"--out {out} is a directory", "name the file to write, e.g. lobby.pcrec"
            )
        try:
            path = asyncio.run(record(args))
        except Exception as exc:  # the server's refusal, no server, a file: code and hint
            failure(P, exc, args.url)
    if args.bvh is not None:
        try:
            with open_recording(path) as recording:  # read record by record
                exported = export_bvh(recording, args.bvh)
        except Exception as exc:
            failure(P, exc, args.url or "")
        for player, bvh in exported.items():
            print(f"{player}: {bvh}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
