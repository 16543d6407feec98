"""The v1 routing cost per tick: ``Hub.deliver`` and every outbox take, P v1 players.

    python benchmarks/route_v1.py 32

One room of P v1 players (joined through the real admission path), 300 ticks of P
synthetic v1 poses, the CPU time per tick, the least of 5 runs. It runs on older
trees too, to compare before and after a change::

    git archive 9f4c1e6 server/posecast | tar -x -C /tmp/before
    PYTHONPATH=/tmp/before/server python benchmarks/route_v1.py 32
"""

from __future__ import annotations

import sys
import time

import numpy as np

from posecast.online.auth.tokens import mint
from posecast.online.config import ServerConfig
from posecast.online.core.hub import Hub
from posecast.online.core.tick import TickOutput
from posecast.online.metrics import Metrics
from posecast.online.protocol import encode
from posecast.online.protocol.messages import Hello, Pose

SECRET = "x" * 40
P = int(sys.argv[1])
cfg = ServerConfig(
    token_secret=SECRET,
    port=0,
    samples=1,
    conn_per_ip_per_min=10_000,
    fatal_per_ip_per_min=10_000,
    sockets_per_ip=10_000,
)
now = 1000.0
hub = Hub(cfg, Metrics(), wall_offset_s=time.time() - now)
conns = []
for i in range(P):
    c = hub.connect("10.0.0.1", now)
    tok = mint(
        SECRET.encode(), room="r", player=f"p{i}", role="player", ttl_s=3600, now=time.time()
    )
    hub.receive(c, encode(Hello(1, tok, "r", f"P{i}")), now)
    conns.append(c)
rng = np.random.default_rng(0)
q = rng.normal(size=(19, 4))
q /= np.linalg.norm(q, axis=1, keepdims=True)
try:  # a tree whose ticks carry PoseOut (one per pose, every protocol's encoder)
    from posecast.testing.poses import pose_out

    poses: list[object] = [
        pose_out(f"p{i}", 1, now, rng.normal(size=(19, 3)) * 0.3, q) for i in range(P)
    ]
except ImportError:  # older trees: (player, v1 bytes)
    poses = [
        (f"p{i}", encode(Pose(f"p{i}", 1, now, rng.normal(size=(19, 3)) * 0.3, q)))
        for i in range(P)
    ]
try:  # a tree with protocol v2: take() wants the time
    from posecast.online.protocol import records

    takes_now = hasattr(records, "PoseState")
except ImportError:
    takes_now = False
best = []
for _ in range(5):
    t0 = time.process_time()
    for _tick in range(300):
        now += 1 / 60
        hub.deliver(TickOutput(poses), now)  # type: ignore[arg-type]
        for c in conns:
            box = hub.outbox(c)
            assert box is not None
            box.take(now) if takes_now else box.take()
    best.append((time.process_time() - t0) / 300 * 1000)
print(P, "players: route ms/tick (min of 5)", round(min(best), 3))
