"""Bandwidth into each client, v1 against v2, for rooms of P players (no sockets).

    python benchmarks/bandwidth.py --rooms 8,16,32 --seconds 10 --samples 10 --json bw.json

The server's own pure core runs here in one process and in simulated time: a ``Hub``
(admission, routing, outboxes) and the engine thread's ``EngineWorker`` on the
shipped models, ticked at 60 Hz as fast as the machine allows. ``P`` players join
one room (over v2; ``--player-protocol 1``: v1) and stream BVH replays (the SDK's
``BvhReplaySource``, one clip per player in turn: ``--bvh`` files, else 8 CMU clips
from ``../shared``; ``--walk``: the SDK's procedural walk, a seed per player), and
three spectators watch: a v1 client, a v2 client at 60 Hz and a v2 client at 20 Hz.
Every client's writer takes its outbox every tick (a client that keeps up, nothing
superseded), so what is counted is exactly what the server would write to it:

* ``payload_kB_s``: WebSocket payload bytes of the messages that carry poses (v1
  ``pose``, one per avatar per tick; v2 ``poses``, one per tick), per second;
* ``wire_kB_s``: the same plus the WebSocket frame headers (2 bytes up to 125
  payload bytes, 4 up to 65535; server frames are unmasked); TCP/IP not included;
* ``bytes_per_pose``: payload bytes per pose received (v2: a message's own
  overhead shared out over its records), as ``posecast-sim`` reports it;
* the v2 60 Hz spectator decodes every message with the Python SDK
  (``AvatarTable``) and compares the rebuilt poses with the v1 ones of the same
  ``seq``: the largest position error (m) and world-rotation error (degrees);
* ``route_ms_per_tick``: CPU time of ``Hub.deliver`` plus the players' outbox
  ``take`` per tick (the v2 records of all clients are prepared in ``deliver``;
  the three watchers' takes are not in it), and
  ``states_ms_per_tick`` the engine thread's v2 pose states for ``P`` poses.

v1 has no pose rate: its 20 Hz figure is derived (``bytes_per_pose`` at 60 Hz times
20 poses a second per avatar), and marked so. The engine's sample count does not
change the bytes much (``--samples``: 10 by default keeps 32 players cheap).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from posecast_client.codec import decode as sdk_decode
from posecast_client.protocol import Pose
from posecast_client.session import ClientSession
from posecast_client.sources import BvhReplaySource, WalkSource

from posecast.online.auth.tokens import mint
from posecast.online.config import ServerConfig
from posecast.online.core.hub import Hub
from posecast.online.engine.config import EngineConfig
from posecast.online.inference.loader import load_multi_engine
from posecast.online.metrics import Metrics
from posecast.online.protocol import encode
from posecast.online.protocol.messages import Frame, Hello
from posecast.online.protocol.records import PoseState
from posecast.online.shell.ticker import EngineWorker

SECRET = "bandwidth-bench-" + "x" * 24
ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "cmu_bvh"  # the CMU clips, when staged
FIXTURES = ROOT / "client_sdk" / "python" / "tests" / "data"  # 0.2 s loops: a smoke test only


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    dot = np.abs(np.einsum("...i,...i->...", a, b))
    cross = np.linalg.norm(
        a[..., 3:] * b[..., :3] - b[..., 3:] * a[..., :3] + np.cross(a[..., :3], b[..., :3]),
        axis=-1,
    )
    return float(np.degrees(2.0 * np.arctan2(cross, dot)).max())


def _header(n: int) -> int:
    return 2 if n <= 125 else 4 if n <= 65535 else 10


class Watcher:
    """One client: the SDK's session decodes what its outbox gives it, and counts."""

    def __init__(self, hub: Hub, conn: int, version: int) -> None:
        self.hub, self.conn = hub, conn
        self.session = ClientSession()
        self.session.connected(version)
        self.wire = self.poses = 0
        self.got: dict[tuple[str, int], Pose] = {}

    def take(self, now: float, keep: bool) -> None:
        box = self.hub.outbox(self.conn)
        assert box is not None
        for data in box.take(now):
            msg = sdk_decode(data, version=self.session.version)
            events, _ = self.session.receive_all(msg, now, len(data))
            poses = [e for e in events if isinstance(e, Pose)]
            if poses:
                self.wire += len(data) + _header(len(data))
                self.poses += len(poses)
            if keep:
                self.got.update(((q.player, q.seq), q) for q in poses)

    @property
    def payload(self) -> int:
        return self.session.stats.pose_bytes

    def reset(self) -> None:
        self.session.stats.pose_bytes = self.wire = self.poses = 0


def states_ms(players: int, repeat: int = 50) -> float:
    """CPU ms the engine thread spends per tick making ``players`` v2 pose states."""
    rng = np.random.default_rng(0)
    q = rng.normal(size=(players, 19, 4)).astype(np.float32)
    pos = rng.normal(size=(players, 19, 3)).astype(np.float32)
    names, seqs = [f"p{i}" for i in range(players)], list(range(players))
    t0 = time.process_time()
    for _ in range(repeat):
        PoseState.batch(names, seqs, 1.0, pos, q, [1.0] * players, [False] * players)
    return 1000 * (time.process_time() - t0) / repeat


def run_room(
    engine: Any, players: int, seconds: float, clips: list[Path], player_version: int = 2
) -> dict[str, Any]:
    """One room of ``players`` for ``seconds`` (simulated); ``clips`` empty: the SDK's
    procedural walk, a different seed per player."""
    cfg = ServerConfig(token_secret=SECRET, port=0, samples=1, max_watchers_per_room=8,
                       conn_per_ip_per_min=10_000, fatal_per_ip_per_min=10_000,
                       sockets_per_ip=10_000)  # fmt: skip
    now = 1000.0
    hub = Hub(cfg, Metrics(), wall_offset_s=time.time() - now)
    room = f"bw-{players}"

    def tok(player: str, role: str = "player") -> str:
        return mint(SECRET.encode(), room=room, player=player, role=role, ttl_s=3600,
                    now=time.time())  # fmt: skip

    conns = []
    for i in range(players):
        c = hub.connect("10.0.0.1", now, player_version)
        hub.receive(c, encode(Hello(player_version, tok(f"p{i}"), room, f"P{i}")), now)
        conns.append(c)
    watchers = []
    for name, version, rate in (("v1", 1, None), ("v2", 2, None), ("v2_20", 2, 20.0)):
        c = hub.connect("10.0.0.2", now, version)
        hub.receive(c, encode(Hello(version, tok(f"w-{name}", "spectator"), room, name,
                                    pose_rate_hz=rate)), now)  # fmt: skip
        watchers.append(Watcher(hub, c, version))
    for c in conns:
        hub.outbox(c).take(now)  # type: ignore[union-attr]

    def source(i: int) -> Any:
        at = ((i % 6) * 1.2, 0.0, (i // 6) * 1.2)
        if clips:
            return BvhReplaySource(clips[i % len(clips)], loop=True, offset_m=at)
        return WalkSource(seconds=10.0, seed=i, loop=True, offset_m=at)

    sources = [source(i).samples() for i in range(players)]
    worker = EngineWorker(engine)
    ticks = int(seconds * 60)
    route = 0.0
    warm = 30  # ticks before measuring: the look-ahead fills, the first keyframes go
    for k in range(warm + ticks):
        now += 1 / 60
        for c, src in zip(conns, sources, strict=True):
            s = next(src)
            hub.receive(c, encode(Frame(k, now, s.positions, s.orientations, s.valid)), now)
        out = worker.step(hub.take_tick_input(), now)
        t0 = time.process_time()
        hub.deliver(out, now)
        for c in conns:
            hub.outbox(c).take(now)  # type: ignore[union-attr]
        measuring = k >= warm
        if measuring:
            route += time.process_time() - t0  # the watchers' own decoding is not the server's
        for w in watchers:
            w.take(now, keep=measuring)
            if not measuring:
                w.reset()
    v1, v2, v2_20 = watchers
    both = sorted(set(v1.got) & set(v2.got))
    pos_err = max(float(np.abs(v2.got[k].positions - v1.got[k].positions).max()) for k in both)
    rot_err = max(_angle_deg(v2.got[k].rotations, v1.got[k].rotations) for k in both)
    per_s = 1.0 / seconds

    def row(w: Watcher) -> dict[str, float]:
        return {
            "payload_kB_s": round(w.payload * per_s / 1000, 2),
            "wire_kB_s": round(w.wire * per_s / 1000, 2),
            "poses_per_s": round(w.poses * per_s, 1),
            "bytes_per_pose": round(w.payload / max(1, w.poses), 2),
        }

    v1_row = row(v1)
    v1_20 = {
        "payload_kB_s": round(v1_row["bytes_per_pose"] * 20 * players / 1000, 2),
        "derived": "v1 has no pose rate: bytes_per_pose at 60 Hz x 20 poses/s x P",
    }
    return {
        "players": players,
        "player_protocol": player_version,
        "seconds": seconds,
        "v1_60": v1_row,
        "v2_60": row(v2),
        "v2_20": row(v2_20),
        "v1_20": v1_20,
        "v2_compared_poses": len(both),
        "v2_max_position_error_m": round(pos_err, 5),
        "v2_max_rotation_error_deg": round(rot_err, 4),
        "route_ms_per_tick": round(1000 * route / ticks, 3),
        "states_ms_per_tick": round(states_ms(players), 3),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rooms", default="8,16,32", help="players per room, comma-separated")
    p.add_argument("--seconds", type=float, default=10.0, help="measured seconds per room")
    p.add_argument("--samples", type=int, default=10, help="engine samples per player (10)")
    p.add_argument("--bvh", type=Path, action="append", help="clips to replay (repeatable)")
    p.add_argument("--walk", action="store_true", help="the SDK's procedural walk, not BVH")
    p.add_argument(
        "--player-protocol",
        type=int,
        choices=(1, 2),
        default=2,
        help="the players' own protocol (1: all v1 but two watchers, 'before')",
    )
    p.add_argument("--json", type=Path, help="write the results here")
    args = p.parse_args(argv)
    # Default: every 7th CMU clip (8 different motions); without ../shared, the SDK's
    # two 12-frame fixtures, whose loops teleport every 0.2 s (far more than real motion).
    clips: list[Path] = []
    if not args.walk:
        clips = args.bvh or sorted(SHARED.glob("*/*/*.bvh.gz"))[::7][:8]
        clips = clips or sorted(FIXTURES.glob("*.bvh"))
    ecfg = EngineConfig(samples=args.samples)
    results = []
    for players in (int(x) for x in args.rooms.split(",")):
        engine = load_multi_engine(ecfg, ["hmd3+waist"])
        r = run_room(engine, players, args.seconds, clips, args.player_protocol)
        results.append(r)
        print(json.dumps(r), flush=True)
    if args.json is not None:
        report = {"clips": [str(c) for c in clips], "samples": args.samples, "rooms": results}
        args.json.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
