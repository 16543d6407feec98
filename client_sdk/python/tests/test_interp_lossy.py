"""The jitter buffer under a lossy link, deterministically (issue 14: "under a lossy
relay, the SDK's interpolated stream at 90 Hz has a largest joint jump no more than
1.5x the clean stream's").

The link is simulated, like the reliability suite's ``LossyRelay``
(``server/posecast/testing/relay.py``): each pose is dropped with probability 0.2
and held a random 0-40 ms (so poses overtake each other), seeded; a clean link
delivers every pose after the same 5 ms. A 90 Hz display samples an
:class:`~posecast_client.interp.PoseBuffer` fed with what has arrived by each of its
frames. Clocks are simulated, so nothing races: the same seed, the same numbers.

Motion: the SDK's built-in walk (the motion of the golden BVH files) on the canonical
skeleton, and, where ``../shared/data`` is present, CMU captures read with the SDK's
own BVH reader (every joint of the 31-joint rig).

``pytest -s`` prints the figures docs/game-engines.md quotes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from posecast_client.bvh import read_bvh
from posecast_client.interp import DEFAULT_INTERP, InterpConfig, PoseBuffer
from posecast_client.protocol import Pose
from posecast_client.rotations import F64, fk, mat2quat, quat2mat
from posecast_client.skeleton import PARENTS, reference_offsets
from posecast_client.sources.walk import walk_motion

POSE_HZ, DISPLAY_HZ = 60.0, 90.0
DROP, HOLD_S, LATENCY_S = 0.2, 0.040, 0.005
T0 = 1000.0  # server time of the first pose
SHARED = Path(__file__).resolve().parents[4] / "shared" / "data" / "cmu_bvh"


@dataclass(frozen=True)
class Link:
    """Which poses arrive, and when (server clock; the client's is the same here)."""

    arrive_s: F64  # (F,) arrival time of each pose; inf: dropped


def lossy_link(n: int, seed: int) -> Link:
    rng = np.random.default_rng(seed)
    t = T0 + np.arange(n) / POSE_HZ
    arrive = t + LATENCY_S + rng.uniform(0.0, HOLD_S, size=n)
    arrive[rng.random(n) < DROP] = np.inf
    return Link(arrive)


def clean_link(n: int) -> Link:
    return Link(T0 + np.arange(n) / POSE_HZ + LATENCY_S)


def display(
    pos: F64, rot: F64, link: Link, *, buffered: bool = True, config: InterpConfig = DEFAULT_INTERP
) -> F64:
    """Joint positions ``(frames, J, 3)`` a 90 Hz display shows: the buffer's sample at
    each frame, or (``buffered=False``) the newest pose that has arrived, as an SDK
    user without a buffer would draw."""
    n = len(pos)
    poses = [Pose("ada", k, T0 + k / POSE_HZ, pos[k], rot[k]) for k in range(n)]
    order = [k for k in np.argsort(link.arrive_s, kind="stable") if np.isfinite(link.arrive_s[k])]
    buf = PoseBuffer(config)
    newest: Pose | None = None
    frames = []
    nxt = 0
    start, end = T0 + 0.3, T0 + (n - 1) / POSE_HZ  # after the buffer filled, to the end
    for now in np.arange(start, end, 1.0 / DISPLAY_HZ):
        while nxt < len(order) and link.arrive_s[order[nxt]] <= now:
            p = poses[order[nxt]]
            buf.push(p)
            if newest is None or p.t > newest.t:
                newest = p
            nxt += 1
        if buffered:
            shown = buf.pose_at(float(now))
            assert shown is not None
            frames.append(shown.positions)
        else:
            assert newest is not None
            frames.append(newest.positions)
    return np.stack(frames)


def max_jump_m(frames: F64) -> float:
    """The largest distance one joint moves between two consecutive displayed frames."""
    return float(np.linalg.norm(np.diff(frames, axis=0), axis=-1).max())


def walk_stream(seconds: float, seed: int) -> tuple[F64, F64]:
    root, local_quat = walk_motion(seconds=seconds, fps=POSE_HZ, seed=seed)
    world, pos = fk(quat2mat(local_quat), root, reference_offsets(), PARENTS)
    return pos, mat2quat(world)


def bvh_stream(path: Path, seconds: float) -> tuple[F64, F64]:
    bvh = read_bvh(path)
    step = round(1.0 / bvh.frame_time_s / POSE_HZ)  # 120 fps -> every other frame
    world, pos = bvh.fk(0.056444)  # the cmu_mb unit
    n = int(seconds * POSE_HZ)
    return pos[1::step][:n], mat2quat(world[1::step][:n])  # frame 0 is a T-pose


def jumps(pos: F64, rot: F64, seed: int) -> dict[str, float]:
    n = len(pos)
    return {
        "clean": max_jump_m(display(pos, rot, clean_link(n))),
        "lossy": max_jump_m(display(pos, rot, lossy_link(n, seed))),
        "lossy_raw": max_jump_m(display(pos, rot, lossy_link(n, seed), buffered=False)),
        "clean_raw": max_jump_m(display(pos, rot, clean_link(n), buffered=False)),
    }


def report(name: str, j: dict[str, float]) -> None:
    print(
        f"\n{name}: largest joint jump per 90 Hz frame, mm: clean {1e3 * j['clean']:.1f}, "
        f"lossy {1e3 * j['lossy']:.1f} ({j['lossy'] / j['clean']:.2f}x); without the "
        f"buffer: clean {1e3 * j['clean_raw']:.1f}, lossy {1e3 * j['lossy_raw']:.1f}"
    )


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_lossy_link_jumps_at_most_one_and_a_half_times_the_clean_ones(seed: int) -> None:
    pos, rot = walk_stream(seconds=30.0, seed=seed)
    j = jumps(pos, rot, seed)
    report(f"walk seed {seed}", j)
    assert j["lossy"] <= 1.5 * j["clean"]
    # The test can fail: without the buffer the same link does not meet the bound.
    assert j["lossy_raw"] > 1.5 * j["clean"]


@pytest.mark.slow
def test_without_rule_5_a_long_burst_shows_as_a_step() -> None:
    """Rule 5 is what keeps the bound over long runs: with ``correction_s=0``, one
    minute of the same link has a burst that runs past the buffer, and the late poses
    correct the extrapolation in one step."""
    pos, rot = walk_stream(seconds=60.0, seed=1)
    n = len(pos)
    clean = max_jump_m(display(pos, rot, clean_link(n)))
    smooth = max_jump_m(display(pos, rot, lossy_link(n, 1)))
    off = InterpConfig(correction_s=0.0)
    abrupt = max_jump_m(display(pos, rot, lossy_link(n, 1), config=off))
    print(
        f"\nwalk seed 1, 60 s: clean {1e3 * clean:.1f} mm, lossy {1e3 * smooth:.1f} mm "
        f"({smooth / clean:.2f}x), lossy with correction_s=0 {1e3 * abrupt:.1f} mm "
        f"({abrupt / clean:.2f}x)"
    )
    assert smooth <= 1.5 * clean < abrupt


def test_the_link_is_as_lossy_as_the_relay() -> None:
    link = lossy_link(60_000, seed=9)
    dropped = float(np.mean(~np.isfinite(link.arrive_s)))
    assert dropped == pytest.approx(DROP, abs=0.01)
    t = T0 + np.arange(60_000) / POSE_HZ
    held = (link.arrive_s - t)[np.isfinite(link.arrive_s)] - LATENCY_S
    assert held.min() >= 0.0 and held.max() <= HOLD_S
    order = np.argsort(link.arrive_s[np.isfinite(link.arrive_s)])
    assert np.any(np.diff(order) < 0), "poses must overtake each other"


CLIPS = ("03/03_03.bvh.gz", "01/01_01.bvh.gz", "08/08_01.bvh.gz")


@pytest.mark.realdata
@pytest.mark.parametrize("clip", CLIPS)
def test_lossy_link_on_motion_capture(clip: str) -> None:
    path = SHARED / "mb" / clip
    if not path.exists():
        pytest.skip(f"{path} not found (../shared/data)")
    pos, rot = bvh_stream(path, seconds=20.0)
    j = jumps(pos, rot, seed=7)
    report(f"CMU {clip}", j)
    assert j["lossy"] <= 1.5 * j["clean"]
