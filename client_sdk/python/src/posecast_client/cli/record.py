"""``posecast-record``: record a room as a spectator, and export players' poses to BVH.

Record (until Ctrl-C, or for ``--seconds``), then optionally export::

    posecast-record --secret $SECRET --room lobby --out lobby.pcrec --seconds 60 --bvh out/

Export an existing recording::

    posecast-record --export lobby.pcrec --bvh out/

The recording format (a msgpack stream) is described in
:mod:`posecast_client.recording`; the BVH files use the canonical 19-joint skeleton,
one per player (``out/<player>.bvh``).

A recording in which no player's pose arrived (a misspelt room, or one nobody was in)
ends with a ``warning:`` naming the room and a ``hint:``: the rooms that have players
when the server says so (a ``--dev`` server answers ``/viewer/rooms`` to a loopback
client; only a server at ``localhost`` or a loopback address is asked), otherwise to
check the room name; no BVH file is written. The exit status is
still 0: the recording is whole, and a room can be empty (1 and 2 stay for what kept
the tool from doing its work: a refusal, no server, a bad file; a command-line
mistake). ``--export`` of a recording without poses warns the same way.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import json
import sys
import time
import urllib.request
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urljoin, urlsplit, urlunsplit

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


@dataclass
class Seen:
    """What a recording caught: messages, poses, the players that were in the room."""

    messages: int = 0
    poses: int = 0
    players: set[str] = field(default_factory=set)
    seconds: float = 0.0

    def add(self, event: Pose | Presence | Error | Welcome) -> None:
        self.messages += 1
        if isinstance(event, Pose):
            self.poses += 1
        elif isinstance(event, Welcome):
            self.players.update(m.player for m in event.members)
        elif isinstance(event, Presence) and event.event == "join":
            self.players.add(event.player)


async def record(args: argparse.Namespace) -> tuple[Path, Seen]:
    out: Path = args.out or Path(f"{args.room}.pcrec")
    seen = Seen()
    stop = asyncio.Event()
    stop_on_signals(stop)
    token = token_for(args, args.room, f"rec-{unique_suffix()}", role="spectator")
    client = await connect_patiently(args.url, token)
    writer = RecordingWriter(out, url=args.url, room=args.room)
    try:
        welcome = await client.join(args.room, args.name)
        writer.write(welcome)
        seen.add(welcome)
        started = time.monotonic()
        print(f"posecast-record: recording {args.room} to {out}", file=sys.stderr)
        timer = asyncio.create_task(asyncio.wait_for(stop.wait(), args.seconds))
        with contextlib.suppress(TimeoutError):
            async for event in client.events(until=timer):
                if isinstance(event, Pose | Presence | Error | Welcome):
                    writer.write(event)
                    seen.add(event)
                elif isinstance(event, Reconnecting):
                    print(f"posecast-record: reconnecting ({event.cause!r})", file=sys.stderr)
            await timer
        seen.seconds = time.monotonic() - started
    finally:
        writer.close()
        await client.close()
    n = writer.count
    print(f"posecast-record: {n} message{'s' * (n != 1)} in {out}", file=sys.stderr)
    return out, seen


MAX_ROOMS_LISTED = 8


def is_loopback_host(url: str) -> bool:
    """Whether ``url``'s host is ``localhost`` or a loopback address literal
    (127.0.0.0/8, ``[::1]``): a server on this machine, asked without a DNS lookup."""
    try:
        host = urlsplit(url).hostname
    except ValueError:
        return False
    if host is None:
        return False
    if host.rstrip(".") == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a name: not resolved here (the 2 s timeout does not cover DNS)
        return False


def server_rooms(url: str, timeout_s: float = 2.0) -> list[tuple[str, int]] | None:
    """The server's open rooms and their player counts, as a ``--dev`` server tells a
    loopback client (``/viewer/rooms`` beside the WebSocket URL); None where it does
    not (a production server, no answer in ``timeout_s``). Only a server on this
    machine (:func:`is_loopback_host`) is asked: a dev server answers nobody else, and
    another host's name would need a DNS lookup no timeout covers."""
    if not is_loopback_host(url):
        return None
    parts = urlsplit(url)
    scheme = "https" if parts.scheme.lower() == "wss" else "http"
    http = urljoin(urlunsplit((scheme, parts.netloc, parts.path or "/", "", "")), "viewer/rooms")
    direct = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # loopback only
    try:
        with direct.open(http, timeout=timeout_s) as response:
            rooms = json.load(response)
        return [(str(r["room"]), int(r["players"])) for r in rooms]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def no_poses_hint(room: str, rooms: list[tuple[str, int]] | None) -> str:
    """What to check when a recording of ``room`` caught no pose; ``rooms``: the
    server's open rooms with their player counts, where it told them."""
    if rooms is None:
        return (
            f"check the room name (--room {room}): is a player in it? "
            "posecast-sim's rooms are sim-0, sim-1, ... (its --room-prefix)"
        )
    others = [(r, n) for r, n in rooms if n > 0 and r != room]
    if not others:
        return "no room on this server has a player now: start the players, or check the URL"
    listed = ", ".join(f"{r} ({n} player{'s' * (n != 1)})" for r, n in others[:MAX_ROOMS_LISTED])
    more = f" and {len(others) - MAX_ROOMS_LISTED} more" if len(others) > MAX_ROOMS_LISTED else ""
    return f"check the room name: players on this server are in {listed}{more}"


def warn_no_poses(room: str, seen: Seen, url: str, bvh: Path | None) -> None:
    """The warning (and hint) for a recording of ``room`` that caught no pose."""
    what = f"no player's pose was seen in room {room} in {seen.seconds:.1f} s"
    if seen.players:
        who = ", ".join(sorted(seen.players)[:MAX_ROOMS_LISTED])
        what += f" (players were in it: {who}; none streamed)"
        hint = "a player's poses arrive once it streams frames: is its tracking running?"
    else:
        hint = no_poses_hint(room, server_rooms(url))
    if bvh is not None:
        what += f"; no BVH written to {bvh}"
    print(f"posecast-record: warning: {what}", file=sys.stderr)
    print(f"hint: {hint}", file=sys.stderr)


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
            path, seen = asyncio.run(record(args))
        except Exception as exc:  # the server's refusal, no server, a file: code and hint
            failure(P, exc, args.url)
        if seen.poses == 0:  # exit 0 all the same: see the module docstring
            warn_no_poses(args.room, seen, args.url, args.bvh)
            return 0
    if args.bvh is not None:
        try:
            with open_recording(path) as recording:  # read record by record
                exported = export_bvh(recording, args.bvh)
                room = recording.header.get("room")
        except Exception as exc:
            failure(P, exc, args.url or "")
        for player, bvh in exported.items():
            print(f"{player}: {bvh}")
        if not exported:
            print(
                f"posecast-record: warning: {path} (room {room}) holds no player's pose; "
                f"no BVH written to {args.bvh}",
                file=sys.stderr,
            )
            print("hint: record a room while its players stream", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
