"""The one model of every tracker set in the SSI engine: mixed sets in one batch."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.train.masks import TABLE_SETS
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.ring import rest_frame
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine
from posecast.tracking.sites import SITE_JOINT_INDEX, Site, TrackerSet


def _walk(t: int, dx: float) -> TrackerFrame:
    """The rest frame of every site walking forward along +Z."""
    rest = rest_frame(10)
    pos = rest.pos.copy()
    pos[:, 0] += dx
    pos[:, 2] += 0.01 * t
    return TrackerFrame(t, pos, rest.quat)


def _run(backend: str) -> dict[str, list[np.ndarray]]:
    e = load_engine(EngineConfig(samples=8), None, 1, "sites", backend)
    names = ("3p", "4p", "6p", "3p+2i")
    for i, n in enumerate(names):
        e.add_player(n, seed=i, tracker_set=TrackerSet.parse(TABLE_SETS[n]))
    out: dict[str, list[np.ndarray]] = {n: [] for n in names}
    for t in range(40):
        for i, n in enumerate(names):
            e.push(n, _walk(t, i * 2.0))
        for p in e.tick().poses:
            out[p.player].append(p.positions)
    return out


def test_mixed_sets_share_one_batch_and_stand_on_their_trackers() -> None:
    out = _run("onnx")
    for i, (name, poses) in enumerate(out.items()):
        assert len(poses) == 40 - EngineConfig().delay, name
        last = poses[-1]
        assert np.isfinite(last).all()
        # Head near its tracker (within reach of the upper-body pass), each player where
        # its own trackers are: 2 m apart along x.
        rest = _walk(len(poses) - 1, i * 2.0).pos
        head = SITE_JOINT_INDEX[0]
        assert np.linalg.norm(last[head] - rest[0]) < 0.1, name
    # A positional waist gives the pelvis: the 4- and 6-point players' sits on it.
    for name in ("4p", "6p"):
        pelvis = out[name][-1][0]
        waist = _walk(len(out[name]) - 1, 2.0 * list(out).index(name)).pos[3]
        assert np.linalg.norm(pelvis - waist) < 1e-4, name
    # Positional foot trackers hold the ankles (the lower-body pass); other sets' feet
    # are the network's.
    for name in ("6p", "4p"):
        t = len(out[name]) - 1
        sites = _walk(t, 2.0 * list(out).index(name)).pos
        for row in (4, 5):  # left_foot, right_foot
            ankle = out[name][-1][SITE_JOINT_INDEX[row]]
            miss = np.linalg.norm(ankle - sites[row])
            assert (miss < 1e-4) if name == "6p" else (miss > 1e-3), (name, row, miss)


@pytest.mark.parametrize("backend", ["native", "torch"])
def test_backends_agree_on_mixed_sets(backend: str) -> None:
    ref, got = _run("onnx"), _run(backend)
    for name in ref:
        diff = np.abs(np.array(ref[name]) - np.array(got[name])).max()
        assert diff < 1e-3, (name, diff)


def test_a_sites_engine_needs_the_set_and_the_multi_engine_routes_sets() -> None:
    e = load_engine(EngineConfig(samples=4), None, 1, "sites", "onnx")
    with pytest.raises(ValueError, match="tracker set"):
        e.add_player("a", 0)
    four = load_engine(EngineConfig(samples=4), None, 1, "hmd3+waist", "onnx")
    multi = MultiEngine({"sites": e, "hmd3+waist": four})
    multi.add_player("s", 0, TrackerSet.parse(TABLE_SETS["8p"]))
    multi.add_player("w", 1, "hmd3+waist")
    assert multi.counts() == {"sites": 1, "hmd3+waist": 1}
    assert TrackerSet.parse(TABLE_SETS["8p"]).kind(Site.LEFT_KNEE) == 1


def test_a_set_that_senses_its_legs_keeps_its_height() -> None:
    """The headset 30 cm under the rest frame's head (a crouch the network does not
    see): the 3-point player's guessed body drops toward it (``torso_span``: its
    spine kept as far from the headset as the network's head is), the player with two
    foot IMUs keeps the height its legs give (the leg pass would sink its feet again),
    the move switched off or not."""
    names = ("3p", "3p+2i")
    pelvis: dict[bool, dict[str, np.ndarray]] = {}
    for drop in (True, False):
        e = load_engine(EngineConfig(samples=8, torso_span=drop), None, 1, "sites", "onnx")
        for i, n in enumerate(names):
            e.add_player(n, seed=i, tracker_set=TrackerSet.parse(TABLE_SETS[n]))
        got: dict[str, list[np.ndarray]] = {n: [] for n in names}
        for t in range(40):
            for i, n in enumerate(names):
                f = _walk(t, i * 2.0)
                f.pos[0, 1] -= 0.3
                e.push(n, f)
            for p in e.tick().poses:
                got[p.player].append(p.positions[0])
        pelvis[drop] = {n: np.stack(v) for n, v in got.items()}
    moved = {n: pelvis[True][n][:, 1] - pelvis[False][n][:, 1] for n in names}
    assert moved["3p"][-10:].max() < -0.01
    np.testing.assert_array_equal(moved["3p+2i"], 0.0)


def test_a_set_waiting_for_its_first_frame_reads_no_acceleration() -> None:
    """Before its first frame a player stands on the rest frame; its inertial sites'
    features (accelerations) are zero, not the rest pose's joint positions."""
    e = load_engine(EngineConfig(samples=4), None, 1, "sites", "onnx")
    e.add_player(
        "p",
        0,
        tracker_set=TrackerSet.parse(
            "head,left_hand,right_hand,waist:imu,left_foot:imu,right_foot:imu"
        ),
    )
    e.tick()
    x, pos, _ = e.newest_inputs("p")
    inertial = [3, 4, 5]  # waist, left foot, right foot: their rows of the frame
    assert np.all(pos[inertial] == 0.0)
    assert np.any(pos[[0, 1, 2]] != 0.0)  # the positional sites stand in the rest pose
    assert np.all(np.isfinite(x))
