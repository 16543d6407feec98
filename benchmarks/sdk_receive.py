"""The Python SDK's receive and display path, this tree against another revision:
``python benchmarks/sdk_receive.py [--ref main] [--players 8] [--ticks 600]
[--rounds 5] [--json out.json]``.

What one player of a room of ``--players`` pays each tick and each display frame,
the work of a client of ``posecast bench latency`` (and of a Python VR client):

* ``decode``: one v2 ``poses`` message of the room's ``--players`` records (deltas,
  the server's own encoder, a keyframe first) through ``codec.decode`` and
  ``ClientSession.receive_all``: bytes to :class:`Pose` events with positions;
* ``feed``: those poses into an :class:`Interpolator` (``feed``);
* ``sample``: one 90 Hz display frame, ``Interpolator.poses_at`` of every player
  (the adaptive render delay, poses arriving 2 ms after their tick);
* ``frame``: one outgoing tracker frame, ``ClientSession.frame`` and ``codec.encode``.

The messages are made once, here, with the server's encoder
(``posecast.online.protocol.records``) from a smooth made-up motion (every joint
turning along a sine path, the pelvis walking). Each revision's SDK runs the same
messages in a child process of its own (``--ref REV``: that revision's
``client_sdk/python/src`` from ``git archive``; this tree's otherwise), the two in turn
for ``--rounds`` rounds, so machine load hits both alike. Prints, per step, the
median over rounds of each round's per-call median in microseconds, and new over old.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
STEPS = ("decode", "feed", "sample", "frame")
TICK_HZ, DISPLAY_HZ, T0 = 60.0, 90.0, 1000.0


def make_stream(players: int, ticks: int) -> dict[str, Any]:
    """The room's skeletons and ``ticks`` v2 poses messages of ``players`` records each."""
    from posecast.online.protocol import codec, records
    from posecast.online.protocol import messages as m
    from posecast.online.protocol.records import PoseState, write_leb128

    rng = np.random.default_rng(0)
    axes = rng.normal(size=(players, 19, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    amp = rng.uniform(0.1, 0.6, (players, 19))
    freq = rng.uniform(0.3, 1.5, (players, 19))
    phase = rng.uniform(0, 6, (players, 19))
    skeleton = records.skeleton2bytes(records.skeleton_offsets(1.0))
    refs: list[Any] = [None] * players
    messages = []
    for k in range(ticks):
        t = T0 + k / TICK_HZ
        angle = amp * np.sin(2 * np.pi * freq * (k / TICK_HZ) + phase)  # (P, 19)
        items = records.rotvec2quat(axes * angle[..., None])  # (P, 19, 4)
        world = np.stack([records.items2world(q) for q in items])
        pos = np.zeros((players, 19, 3))
        pos[:, 0] = [[0.3 * p + 1.4 * k / TICK_HZ, 0.95, -2.0] for p in range(players)]
        states = PoseState.batch([f"p{p}" for p in range(players)], [k] * players, t, pos,
                                 world, [1.0] * players, [False] * players)  # fmt: skip
        body = b""
        for p, s in enumerate(states):
            assert s is not None
            got = None if refs[p] is None else s.delta(refs[p])
            rec, refs[p] = s.keyframe() if got is None else got
            body += write_leb128(p + 1) + rec
        messages.append((t, codec.encode(m.Poses(t, body))))
    return {"players": players, "skeleton": skeleton, "messages": messages}


def _median_us(times: list[float]) -> float:
    return 1e6 * statistics.median(times)


def child(path: Path) -> dict[str, float]:
    """Run every step over the stream in ``path`` with the SDK on ``sys.path``."""
    import posecast_client as pc
    from posecast_client.codec import decode, encode
    from posecast_client.session import ClientSession

    sdk = Path(os.environ["PYTHONPATH"]).resolve()
    assert Path(pc.__file__).resolve().is_relative_to(sdk), (pc.__file__, sdk)  # that SDK
    w = pickle.loads(path.read_bytes())
    session = ClientSession()
    session.connected(2)
    for p in range(w["players"]):
        session.avatars.announce(f"p{p}", p + 1, w["skeleton"])
    interp = pc.Interpolator()
    times: dict[str, list[float]] = {s: [] for s in STEPS}
    clock = time.perf_counter
    msgs = w["messages"]
    k = 0
    frame_t = msgs[0][0]
    pos = np.array([[0.0, 1.7, 0.0], [-0.3, 1.2, 0.2], [0.3, 1.2, 0.2], [0.0, 1.0, 0.0]])
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
    while k < len(msgs):
        frame_t += 1.0 / DISPLAY_HZ
        while k < len(msgs) and msgs[k][0] + 0.002 <= frame_t:  # arrived by this frame
            data = msgs[k][1]
            a = clock()
            events, _ = session.receive_all(decode(data, version=2), frame_t, len(data))
            b = clock()
            for e in events:
                interp.feed(e)
            c = clock()
            f = session.frame(pos, quat, now=frame_t)
            encode(f)
            d = clock()
            session.sent(f, frame_t)
            assert len(events) == w["players"], len(events)
            if k >= 30:  # past the first keyframes
                times["decode"].append(b - a)
                times["feed"].append(c - b)
                times["frame"].append(d - c)
            k += 1
        a = clock()
        shown = interp.poses_at(frame_t)
        b = clock()
        assert len(shown) == w["players"]
        if k >= 30:
            times["sample"].append(b - a)
    return {s: _median_us(v) for s, v in times.items()}


def _sdk_at(ref: str, into: Path) -> Path:
    """``client_sdk/python/src`` at revision ``ref``, extracted under ``into``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "client_sdk/python/src"],
                             check=True, capture_output=True).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into / "client_sdk" / "python" / "src"


def _run_child(src: Path, workload: Path) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, __file__, "--child", str(workload)], env=env,
                         check=True, capture_output=True, text=True).stdout  # fmt: skip
    got: dict[str, float] = json.loads(out.strip().splitlines()[-1])
    return got


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", default="main", help="the revision to compare with (default main)")
    ap.add_argument("--players", type=int, default=8, help="players in the room (records a tick)")
    ap.add_argument("--ticks", type=int, default=600, help="messages (60 Hz ticks) a round")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        workload = Path(tmp) / "stream.pickle"
        workload.write_bytes(pickle.dumps(make_stream(args.players, args.ticks)))
        here = ROOT / "client_sdk" / "python" / "src"
        sdks = {args.ref: _sdk_at(args.ref, Path(tmp)), "this tree": here}
        rounds: dict[str, list[dict[str, float]]] = {name: [] for name in sdks}
        for _ in range(args.rounds):
            for name, src in sdks.items():
                rounds[name].append(_run_child(src, workload))
    med = {n: {s: statistics.median(r[s] for r in rs) for s in STEPS} for n, rs in rounds.items()}
    old, new = med[args.ref], med["this tree"]
    print(
        f"Python SDK, one player of a room of {args.players}: microseconds per call, "
        f"median of {args.rounds} rounds of {args.ticks} ticks ({DISPLAY_HZ:g} Hz display)"
    )
    print(f"{'step':28s} {args.ref:>12s} {'this tree':>12s} {'new/old':>8s}")
    labels = {
        "decode": f"decode ({args.players} records)",
        "feed": f"feed ({args.players} poses)",
        "sample": f"sample ({args.players} players)",
        "frame": "frame out",
    }
    for s in STEPS:
        print(f"{labels[s]:28s} {old[s]:12.1f} {new[s]:12.1f} {new[s] / old[s]:8.2f}")
    tick = {n: TICK_HZ * (v["decode"] + v["feed"] + v["frame"]) + DISPLAY_HZ * v["sample"]
            for n, v in med.items()}  # fmt: skip
    print(f"{'a core per player (60 Hz)':28s} {tick[args.ref] / 1e6:12.4f} "
          f"{tick['this tree'] / 1e6:12.4f} {tick['this tree'] / tick[args.ref]:8.2f}")  # fmt: skip
    if args.json is not None:
        config = {k: v for k, v in vars(args).items() if k not in ("json", "child")}
        cores = {n: v / 1e6 for n, v in tick.items()}
        report = {"config": config, "us": med, "rounds": rounds, "cores_per_player": cores}
        args.json.write_text(json.dumps(report, indent=1, default=str) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
