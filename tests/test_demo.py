"""``posecast demo`` as a library (posecast.demo): the motion its headsets replay, and a
short run on a BVH file in which both simulated players' avatars reach the spectator
(the CLI's flags, errors and SIGTERM are ``tests/cli/test_serve.py``'s)."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import numpy as np
import pytest

from posecast.demo import motion, run
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh


def test_the_headsets_replay_a_generated_walk_or_the_given_file(tmp_path: Path) -> None:
    walk = motion(None, 1)
    assert walk["tracker_pos"].shape == (720, 4, 3)  # 12 s at 60 Hz
    assert walk["tracker_quat"].shape == (720, 4, 4)
    assert not np.allclose(walk["tracker_pos"], motion(None, 2)["tracker_pos"])  # per seed
    bvh = tmp_path / "01_01.bvh"
    write_fixture_bvh(bvh, walk_clip(seconds=1.0, fps=120.0, seed=3), "cmu_mb")
    replay = motion(bvh, 1)
    assert 55 <= len(replay["tracker_pos"]) <= 61  # a second, at the prepared 60 Hz
    np.testing.assert_array_equal(replay["features"], motion(bvh, 2)["features"])


@pytest.mark.timeout(120)
def test_a_short_run_streams_both_players_to_the_spectator(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bvh = tmp_path / "01_01.bvh"
    write_fixture_bvh(bvh, walk_clip(seconds=2.0, fps=120.0, seed=4), "cmu_mb")
    asyncio.run(run(0, 4.5, bvh, 8))
    out = capsys.readouterr().out
    port = re.search(r"server on ws://127\.0\.0\.1:(\d+)/", out)
    assert port is not None and f"http://127.0.0.1:{port[1]}/viewer?room=demo" in out
    rates = {m[1]: float(m[2]) for m in re.finditer(r"^(\w+):\s+([\d.]+) poses/s", out, re.M)}
    assert set(rates) == {"alice", "bob"}, out  # Alice (hmd3+waist) and Bob (hmd3)
    assert all(r > 0 for r in rates.values()), rates
