"""Tracker sets in the Python SDK: parsing (the server's rule), `sites` frames and
T-poses on the wire, the session's row checks, and replay sources of any set."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from posecast_client import sites
from posecast_client.codec import decode, encode
from posecast_client.errors import BadFieldError, OutOfRangeError
from posecast_client.protocol import Calibrate, Frame, Hello
from posecast_client.session import ClientSession
from posecast_client.sources import BvhReplaySource, WalkSource
from posecast_client.sources.walk import write_walk_bvh

SIX = "head,left_hand,right_hand,waist,left_foot,right_foot"
IMU = "head,left_hand,right_hand,left_foot:imu,right_foot:imu"
DATA = Path(__file__).resolve().parent / "data"


def test_tables_match_the_server() -> None:
    server = pytest.importorskip("posecast.tracking.sites")
    assert tuple(s.value for s in server.SITES) == sites.SITES
    assert tuple(map(int, sites.SITE_JOINTS.values())) == server.SITE_JOINT_INDEX
    assert sites.INERTIAL_SUFFIX == server.INERTIAL_SUFFIX


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("head,left_hand", "needs a 'right_hand'"),
        ("head,left_hand,right_hand,tail", "unknown site 'tail'"),
        ("head,left_hand,right_hand,waist,waist", "listed twice"),
        ("head:imu,left_hand,right_hand", "positional 'head'"),
        ("", "non-empty"),
    ],
)
def test_bad_sets_say_why_as_the_server_does(text: str, why: str) -> None:
    with pytest.raises(ValueError, match=why):
        sites.TrackerSet.parse(text)
    server = pytest.importorskip("posecast.tracking.sites")
    with pytest.raises(ValueError, match=why):
        server.TrackerSet.parse(text)


def test_a_set_round_trips_by_name() -> None:
    ts = sites.TrackerSet.parse(IMU)
    assert ts.name == IMU and len(ts) == 5 and ts.all_valid == 31
    assert ts.inertial == (False, False, False, True, True)
    assert sites.tracker_set("hmd3") is None and sites.tracker_set(None) is None


def test_set_hellos_frames_and_tposes_on_the_wire() -> None:
    hello = decode(encode(Hello("tok", "r", "n", SIX)))
    assert isinstance(hello, Hello) and hello.layout == SIX
    rows = np.tile([0.1, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0], (6, 1))
    f = Frame(3, 1.5, rows[:, :3], rows[:, 3:], valid=0b110111, sites=True)
    got = decode(encode(f))
    assert isinstance(got, Frame) and got.sites and got.valid == 0b110111
    np.testing.assert_allclose(got.positions[:3], rows[:3, :3])
    np.testing.assert_allclose(got.positions[3], 0.0)  # untracked: origin
    full = decode(encode(Frame(4, 1.6, rows[:, :3], rows[:, 3:], valid=63, sites=True)))
    assert isinstance(full, Frame) and full.valid == 63
    tpose = decode(encode(Calibrate(positions=rows[:, :3], orientations=rows[:, 3:], sites=True)))
    assert isinstance(tpose, Calibrate) and tpose.sites and tpose.positions is not None
    assert tpose.positions.shape == (6, 3)


def test_bad_set_messages_get_their_codes() -> None:
    with pytest.raises(BadFieldError, match="layout"):
        decode(encode(Hello("tok", "r", "n", "head,left_hand")))
    rows = np.tile([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0], (3, 1))
    with pytest.raises(OutOfRangeError, match="beyond the 3 sites"):
        decode(encode(Frame(1, 1.0, rows[:, :3], rows[:, 3:], valid=0b1000, sites=True)))


def test_the_session_checks_a_sets_rows() -> None:
    s = ClientSession(tracker_set=sites.TrackerSet.parse(SIX))
    pos, quat = np.zeros((6, 3)), np.tile([0.0, 0.0, 0.0, 2.0], (6, 1))
    f = s.frame(pos, quat, now=1.0, valid=63)
    assert f.sites and f.positions.shape == (6, 3)
    np.testing.assert_allclose(f.orientations[:, 3], 1.0)  # normalised
    with pytest.raises(ValueError, match=r"\(6, 3\)"):
        s.frame(np.zeros((4, 3)), np.zeros((4, 4)), now=1.0)
    with pytest.raises(ValueError, match=r"0\.\.63"):
        s.frame(pos, quat, now=1.0, valid=64)
    bad = pos.copy()
    bad[5] = np.nan
    with pytest.raises(OutOfRangeError, match=r"sites\[5\]"):
        s.frame(bad, quat, now=1.0, valid=63)


def test_walk_of_a_set_puts_sites_on_their_joints_and_imus_read_accelerations() -> None:
    positional = WalkSource(seconds=2.0, seed=3, tracker_set=SIX)
    inertial = WalkSource(seconds=2.0, seed=3, tracker_set=IMU)
    assert positional.positions.shape == (120, 6, 3)
    # Head and hands agree; the IMU rows are the second difference of the positional
    # feet (same joints), at 60 Hz.
    np.testing.assert_allclose(inertial.positions[:, :3], positional.positions[:, :3])
    feet = positional.positions[:, 4:6]
    second = (feet[2:] - 2 * feet[1:-1] + feet[:-2]) * 3600.0
    np.testing.assert_allclose(inertial.positions[1:-1, 3:5], second, atol=1e-6)
    np.testing.assert_allclose(inertial.orientations[:, 3:5], positional.orientations[:, 4:6])
    sample = next(iter(inertial.samples()))
    assert sample.valid == 31 and sample.positions.shape == (5, 3)


def test_walk_sites_match_the_servers_site_tracks() -> None:
    synthetic = pytest.importorskip("posecast.offline.motion.synthetic")
    server = pytest.importorskip("posecast.tracking.sites")
    clip = synthetic.walk_clip(seconds=2.0, fps=60.0, seed=5)
    pos, quat, _ = server.site_tracks(*clip.fk(), 60.0)
    ours = WalkSource(seconds=2.0, seed=5, tracker_set=",".join(sites.SITES))
    np.testing.assert_allclose(ours.positions, pos, atol=1e-5)
    dots = np.abs((ours.orientations * quat).sum(-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-5)


@pytest.mark.parametrize("rig", ["cmu_mb", "cmu_daz"])
def test_bvh_replay_of_a_set_on_cmu_rigs(rig: str) -> None:
    src = BvhReplaySource(DATA / f"walk_{rig}.bvh", rate_hz=120.0, tracker_set=SIX)
    walk = WalkSource(seconds=0.2, seed=1, rate_hz=120.0, tracker_set=SIX)
    np.testing.assert_allclose(src.positions, walk.positions, atol=1e-5)


def test_bvh_replay_of_a_set_needs_its_joints(tmp_path: Path) -> None:
    path = tmp_path / "walk.bvh"
    write_walk_bvh(path, seconds=1.0, fps=60.0, seed=2)
    src = BvhReplaySource(path, tracker_set=IMU)
    assert src.positions.shape == (60, 5, 3) and src.tracker_set is not None
    with pytest.raises(ValueError, match="unknown site"):
        BvhReplaySource(path, tracker_set="head,left_hand,right_hand,tail")
