"""When a pose is first displayed, and joint jumps at the display rate
(posecast.offline.evaluation.latency.display)."""

from __future__ import annotations

import numpy as np
import posecast_client as pc

from posecast.offline.evaluation.latency.display import Displayed, DisplayWatch, JumpMeter


def test_a_pose_is_displayed_on_the_first_frame_whose_shown_time_reaches_it() -> None:
    w = DisplayWatch()
    w.received("a", 7, t=1.00, at=1.01)
    w.received("a", 8, t=1.02, at=1.03)
    assert w.frame(1.05, {"a": 0.999}) == []  # shown time short of both
    assert w.frame(1.06, {"a": 1.00}) == [Displayed("a", 7, 1.00, 1.01, 1.06)]  # reaches: shown
    assert w.frame(1.07, {"a": 1.019}) == []  # 7 is not shown twice
    assert w.frame(1.08, {"a": 5.0}) == [Displayed("a", 8, 1.02, 1.03, 1.08)]
    assert list(w.waiting()) == []


def test_a_late_pose_is_displayed_on_the_next_frame_and_senders_are_apart() -> None:
    w = DisplayWatch()
    assert w.frame(2.00, {"a": 1.5, "b": 1.5}) == []
    w.received("a", 1, t=1.40, at=2.005)  # arrives after the shown time passed it
    w.received("b", 1, t=1.60, at=2.005)
    w.received("b", 0, t=1.55, at=2.006)  # out of order: kept sorted by t
    shown = w.frame(2.011, {"a": 1.511, "b": 1.58})
    assert shown == [Displayed("a", 1, 1.40, 2.005, 2.011), Displayed("b", 0, 1.55, 2.006, 2.011)]
    assert list(w.waiting()) == [("b", 1, 1.60, 2.005)]
    w.forget("b")  # left: never displayed
    assert list(w.waiting()) == []


def test_the_sdk_interpolator_displays_every_pose_once_in_order() -> None:
    """Poses at 60 Hz arriving on time, the SDK's own interpolator sampled at 90 Hz:
    every pose is displayed once, in order, on the frame whose shown time first
    reaches it (the frame before showed an earlier time), whatever the render delay."""
    interp, w = pc.Interpolator(), DisplayWatch()
    pos = np.zeros((19, 3))
    shown_t: dict[float, float] = {}  # frame time -> shown time
    displayed: list[Displayed] = []
    k_pose, frame = 0, 0
    while frame < 180:  # two seconds at 90 Hz; times on one clock (server = client)
        now = frame / 90.0
        while k_pose / 60.0 <= now and k_pose < 90:  # 1.5 s of poses, each on time
            t = k_pose / 60.0
            interp.push(pc.Pose("a", k_pose, t, pos + np.array([t, 0.0, 0.0])))
            w.received("a", k_pose, t, at=t)
            k_pose += 1
        s = interp.poses_at(now)["a"]
        shown_t[now] = s.t
        displayed += w.frame(now, {"a": s.t})
        frame += 1
    assert [d.seq for d in displayed] == list(range(90))  # each once, in order
    frames = sorted(shown_t)
    for d in displayed:
        i = frames.index(d.shown)
        assert shown_t[d.shown] >= d.t and d.shown >= d.received
        assert i == 0 or shown_t[frames[i - 1]] < d.t or frames[i - 1] < d.received


def test_jumps_are_per_nominal_frame_and_only_in_the_window() -> None:
    m = JumpMeter(display_hz=100.0)
    p0 = np.zeros((2, 3))
    m.frame(0.00, {"a": p0}, record=False)
    m.frame(0.01, {"a": p0 + np.array([0.0, 0.03, 0.0])})  # on time: 3 cm
    m.frame(0.03, {"a": p0 + np.array([0.0, 0.07, 0.0])})  # two periods late: 4 cm counts as 2
    m.frame(0.035, {"a": p0 + np.array([0.0, 0.08, 0.0])})  # early: as it is
    m.frame(0.045, {"a": p0 + np.array([0.0, 0.08, 0.0]), "b": p0})  # b's first frame: no jump yet
    m.forget("a")
    m.frame(0.055, {"a": p0 + np.array([5.0, 0.0, 0.0])}, record=True)  # a after forget: no jump
    np.testing.assert_allclose(m.jumps_m, [0.03, 0.02, 0.01, 0.0])
