"""The decode benchmark's input and its Python figures (client_sdk/csharp/README.md).

Writes a 60 s, 8-player room as one client receives it (procedural walks at 60 Hz,
each player 2 m apart), twice: as posecast.v2 (a welcome, then one poses message per
tick, records made by the server's own encoder: keyframes every second, deltas
between) and as posecast.v1 (one pose message per player per tick). Then measures,
on one core (process CPU time), how many poses per second the Python SDK decodes
(v1 pose messages) and the server's reference v2 decoder rebuilds (records + FK),
and prints them as one JSON line. The C# figures come from `PosecastTests.exe --bench`.

    .venv/bin/python client_sdk/csharp/Tests~/bench_stream.py OUT_DIR
"""

from __future__ import annotations

import json
import struct
import sys
import time
from pathlib import Path

import numpy as np
import posecast_client as pc

from posecast.geometry.rotations import quat2mat
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.protocol import codec, records
from posecast.online.protocol import messages as m
from posecast.skeleton import NUM_JOINTS, PARENTS

PLAYERS, SECONDS, HZ = 8, 60.0, 60.0


def world_and_positions(
    local: np.ndarray, root: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: world rotations (F, 19, 4) and FK positions (F, 19, 3)."""
    world = np.stack([records.items2world(q) for q in local])
    mats = quat2mat(world)  # (F, 19, 3, 3)
    pos = np.empty((len(local), NUM_JOINTS, 3))
    pos[:, 0] = root
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        pos[:, j] = pos[:, p] + np.einsum("fij,j->fi", mats[:, p], offsets[j])
    return world, pos


def frames(path: Path, blobs: list[bytes]) -> None:
    path.write_bytes(b"".join(struct.pack("<I", len(b)) + b for b in blobs))


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    ticks = int(SECONDS * HZ)
    players = [f"p-{i}" for i in range(PLAYERS)]
    offsets = records.skeleton_offsets(1.0)
    skeleton = records.skeleton2bytes(offsets)
    full = np.vstack([np.zeros(3), offsets])
    motion = []
    for i in range(PLAYERS):
        clip = walk_clip(seconds=SECONDS, fps=HZ, seed=i)
        motion.append(
            world_and_positions(
                clip.local_quat, clip.root_pos + np.array([2.0 * i, 0.0, 0.0]), full
            )
        )
    members = tuple(m.Member(p, p, i, skeleton) for i, p in enumerate(players))
    welcome = m.Welcome(2, "spectator-1", "s-1", "spectator", "bench", 0.0, 60.0, 2, members,
                        m.DEFAULT_LIMITS, 60.0)  # fmt: skip
    v2 = [codec.encode(welcome)]
    v1 = []
    refs: dict[int, records.Recon] = {}
    last_key: dict[int, float] = {}
    keyframes = 0
    for k in range(ticks):
        t = 10.0 + k / HZ
        parts = []
        for i, player in enumerate(players):
            world, pos = motion[i][0][k], motion[i][1][k]
            state = records.PoseState.from_engine(player, k, t, pos, world)
            got = None
            if i in refs and t - last_key[i] < 1.0 - 0.5 / HZ:
                got = state.delta(refs[i])
            if got is None:
                got = state.keyframe()
                last_key[i] = t
                keyframes += 1
            body, refs[i] = got
            parts.append(records.write_leb128(i) + body)
            v1.append(codec.encode(m.Pose(player, k, t, pos, world)))
        v2.append(codec.encode(m.Poses(t, b"".join(parts))))
    frames(out / "room_v2.bin", v2)
    frames(out / "room_v1.bin", v1)
    poses = ticks * PLAYERS

    def best_rate(fn: object) -> float:
        rates = []
        for _ in range(3):
            c0 = time.process_time()
            fn()  # type: ignore[operator]
            rates.append(poses / (time.process_time() - c0))
        return max(rates)

    def python_sdk_v1() -> None:
        for b in v1:
            pc.decode(b)

    bones = records.bytes2skeleton(skeleton)

    def reference_v2() -> None:
        r: dict[int, records.Recon | None] = dict.fromkeys(range(PLAYERS))
        for b in v2[1:]:
            msg = codec.decode(b, version=2)
            assert isinstance(msg, m.Poses)
            for rec in records.decode_records(msg.data, r):
                rec.recon.positions(bones)

    print(json.dumps({
        "poses": poses,
        "v2_bytes_per_pose": round(sum(map(len, v2[1:])) / poses, 1),
        "v1_bytes_per_pose": round(sum(map(len, v1)) / poses, 1),
        "v2_keyframes": keyframes,
        "python_sdk_v1_poses_per_s": round(best_rate(python_sdk_v1)),
        "python_reference_v2_poses_per_s": round(best_rate(reference_v2)),
    }))  # fmt: skip


if __name__ == "__main__":
    main(Path(sys.argv[1]))
