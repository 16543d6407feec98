"""One connection's state machine (posecast.online.core.session), without sockets."""

from __future__ import annotations

import time

import numpy as np
import pytest

from posecast.errors import (
    AlreadyJoinedError,
    CalibrationFailedError,
    DuplicateError,
    ForbiddenError,
    LayoutUnsupportedError,
    NotJoinedError,
    OutOfOrderError,
    RateLimitedError,
    TokenExpiredError,
    UnauthenticatedError,
)
from posecast.online.core.session import (
    CalibrateIn,
    FrameIn,
    Join,
    KickIn,
    Leave,
    Phase,
    Reply,
    SelectorIn,
    Session,
)
from posecast.online.engine.selectors import DefaultSelector, ObstacleSelector, TargetSelector
from posecast.online.protocol.messages import Bye, Calibrate, Hello, Kick, Ping, Pong, Selector
from posecast.skeleton import Joint
from tests.online.conftest import make_cfg, token, walk_frame


def _session(**cfg: object) -> Session:
    return Session(1, "127.0.0.1", make_cfg(**cfg), opened_at=time.time())


def _joined(role: str = "player", **cfg: object) -> Session:
    s = _session(**cfg)
    join = s.handle(Hello(1, token(role=role), "r1", "Ann"), time.time())
    assert isinstance(join, Join)
    s.joined(join)
    return s


def test_hello_with_a_good_token_asks_to_join() -> None:
    s = _session()
    join = s.handle(Hello(1, token(), "r1", "Ann"), time.time())
    assert isinstance(join, Join) and join.rooms == ("r1",) and join.claims.player == "p1"
    s.joined(join)
    assert s.phase is Phase.JOINED and s.player == "p1" and s.role == "player"


def test_anything_before_hello_is_not_joined() -> None:
    with pytest.raises(NotJoinedError) as e:
        _session().handle(walk_frame(0), time.time())
    assert e.value.fatal


@pytest.mark.parametrize(
    ("hello", "error"),
    [
        (Hello(1, "garbage", "r1", "A"), UnauthenticatedError),
        (Hello(1, token()[:-3] + "AAA", "r1", "A"), UnauthenticatedError),
        (Hello(1, token(room="r2"), "r1", "A"), ForbiddenError),
        (Hello(1, token(role="spectator"), "r1", "A", watch=("r2",)), ForbiddenError),
    ],
)
def test_bad_hellos_are_fatal(hello: Hello, error: type[Exception]) -> None:
    with pytest.raises(error) as e:
        _session().handle(hello, time.time())
    assert e.value.fatal  # type: ignore[attr-defined]


@pytest.mark.parametrize("layout", [None, "hmd3+waist", "hmd3"])
def test_the_hello_layout_is_kept_when_served(layout: str | None) -> None:
    s = _session(layouts="hmd3+waist,hmd3")
    join = s.handle(Hello(1, token(), "r1", "A", layout=layout), time.time())
    assert isinstance(join, Join)
    s.joined(join)
    assert s.layout == (layout or "hmd3+waist")


def test_a_layout_the_server_does_not_serve_is_fatal() -> None:
    s = _session(layouts="hmd3+waist")
    with pytest.raises(LayoutUnsupportedError) as e:
        s.handle(Hello(1, token(), "r1", "A", layout="hmd3"), time.time())
    assert e.value.fatal and e.value.field == "layout"
    assert e.value.message == (  # what is served, and how to serve it
        "layout 'hmd3' is not served here (layouts hmd3+waist): start the server with hmd3"
        " in its layouts, --layouts hmd3+waist,hmd3 (POSECAST_LAYOUTS)"
    )


def test_a_bad_token_learns_nothing_of_the_layouts_served() -> None:
    # The token is checked first: the served layouts and the option that serves
    # them are for clients the server admits, not for anyone who opens a socket.
    s = _session(layouts="hmd3+waist")
    with pytest.raises(UnauthenticatedError) as e:
        s.handle(Hello(1, "garbage", "r1", "A", layout="hmd3"), time.time())
    assert "layouts" not in e.value.message


def test_expired_token() -> None:
    s = _session(token_leeway_s=1.0)
    with pytest.raises(TokenExpiredError):
        s.handle(Hello(1, token(ttl_s=1), "r1", "A"), time.time() + 10)


def test_backend_watches_only_rooms_in_its_token() -> None:
    tok = token(role="backend", rooms=("r2", "r3"))
    join = _session().handle(Hello(1, tok, "r1", "B", watch=("r2", "r3")), time.time())
    assert isinstance(join, Join) and join.rooms == ("r1", "r2", "r3")
    with pytest.raises(ForbiddenError) as refused:
        _session().handle(Hello(1, tok, "r1", "B", watch=("r4",)), time.time())
    assert refused.value.fatal  # FORBIDDEN at hello ends the connection (proto/README.md)


def test_frames_in_order_pass_and_others_are_dropped() -> None:
    s = _joined()
    now = time.time()
    out = s.handle(walk_frame(5), now)
    assert isinstance(out, FrameIn) and out.frame.seq == 5
    with pytest.raises(DuplicateError) as dup:
        s.handle(walk_frame(5), now)
    assert dup.value.ref_seq == 5 and not dup.value.fatal
    with pytest.raises(OutOfOrderError):
        s.handle(walk_frame(4), now)
    assert isinstance(s.handle(walk_frame(9), now), FrameIn)  # a gap is fine


def test_seq_wraps_around() -> None:
    s = _joined()
    now = time.time()
    s.handle(walk_frame(2**32 - 1), now)
    assert isinstance(s.handle(walk_frame(0), now), FrameIn)


def test_invalid_tracker_slots_hold_their_last_pose() -> None:
    s = _joined()
    now = time.time()
    first = s.handle(walk_frame(0), now)
    f1 = walk_frame(1)
    pos = f1.pos.copy()
    pos[3] = 0.0  # what a decoder gives an invalid slot
    lost = type(f1)(1, f1.t, pos, f1.quat, valid=0b0111)  # the waist tracker is lost
    out = s.handle(lost, now)
    assert isinstance(first, FrameIn) and isinstance(out, FrameIn)
    np.testing.assert_array_equal(out.frame.pos[3], first.frame.pos[3])
    np.testing.assert_array_equal(out.frame.pos[:3], f1.pos[:3])


def test_frame_rate_is_limited_by_a_token_bucket() -> None:
    s = _joined(max_rate_hz=60, rate_burst=5)
    now = time.time()
    results = []
    for seq in range(10):
        try:
            s.handle(walk_frame(seq), now)
            results.append(True)
        except RateLimitedError as e:
            assert e.ref_seq == seq
            results.append(False)
    assert results == [True] * 5 + [False] * 5


@pytest.mark.parametrize(
    ("role", "msg"),
    [
        ("spectator", walk_frame(0)),
        ("spectator", Calibrate(height_m=1.7)),
        ("player", Kick("p2")),
        ("player", Selector("p2", "anomaly")),
        ("backend", walk_frame(0)),
        ("player", Pong(1.0, 2.0, 3.0)),
    ],
)
def test_roles_may_not_send_what_is_not_theirs(role: str, msg: object) -> None:
    s = _joined(role)
    with pytest.raises(ForbiddenError) as e:
        s.handle(msg, time.time())  # type: ignore[arg-type]
    assert not e.value.fatal


def test_second_hello_is_already_joined() -> None:
    with pytest.raises(AlreadyJoinedError):
        _joined().handle(Hello(1, token(), "r1", "A"), time.time())


def test_ping_pong_bye_calibrate() -> None:
    s = _joined()
    now = time.time()
    reply = s.handle(Ping(t0=12.5), now)
    assert isinstance(reply, Reply) and reply.message == Pong(12.5, now, now)
    assert s.clock.samples == 1
    cal = s.handle(Calibrate(height_m=1.9), now)
    assert isinstance(cal, CalibrateIn) and cal.calibration.scale < 1.0
    with pytest.raises(CalibrationFailedError):
        s.handle(Calibrate(pos=np.zeros((4, 3)), quat=np.tile([0, 0, 0, 1.0], (4, 1))), now)
    assert isinstance(s.handle(Bye("done"), now), Leave)


def test_backend_selectors_and_kicks() -> None:
    s = _joined("backend")
    now = time.time()
    sel = s.handle(Selector("p2", "target", joint="LEFT_HAND", point=(1.0, 1.0, 0.0)), now)
    assert isinstance(sel, SelectorIn)
    assert sel.selector == TargetSelector(Joint.LEFT_HAND, (1.0, 1.0, 0.0), 0.02)
    obs = s.handle(Selector("p2", "obstacle", joint="HEAD", point=(0, 2, 0), radius_m=0.5), now)
    assert isinstance(obs, SelectorIn)
    assert obs.selector == ObstacleSelector(Joint.HEAD, (0, 2, 0), 0.5)
    anomaly = s.handle(Selector("p2", "anomaly", factor=3.0), now)
    # The engine's own anomaly selector (its configured baseline and home), factor 3.
    assert isinstance(anomaly, SelectorIn) and anomaly.selector == DefaultSelector(3.0)
    kick = s.handle(Kick("p2"), now)
    assert isinstance(kick, KickIn) and kick.player == "p2"


def test_control_messages_are_rate_limited_too() -> None:
    s = _joined(control_rate_hz=5.0)
    now = time.time()
    for _ in range(5):
        s.handle(Ping(1.0), now)
    with pytest.raises(RateLimitedError):
        s.handle(Ping(1.0), now)


# --- tracker sets ------------------------------------------------------------------------

_SET = "head,left_hand,right_hand,left_foot:imu,waist"


def _set_player() -> Session:
    from posecast.tracking.sites import TrackerSet

    s = _session(layouts="hmd3+waist,hmd3,sites")
    join = s.handle(Hello(1, token(), "r1", "Ann", layout=TrackerSet.parse(_SET)), time.time())
    assert isinstance(join, Join)
    s.joined(join)
    return s


def _sites_frame(seq: int, valid: int = 0b11111, rows: int = 5) -> object:
    from posecast.online.protocol.messages import Frame

    pos = np.array([[0, 1.6, 0], [0.3, 1.2, 0.2], [-0.3, 1.2, 0.2], [0.5, -9.0, 2.0], [0, 1, 0]])
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (rows, 1))
    return Frame(seq, 0.1 * seq, pos[:rows].astype(float), quat, valid, sites=True)


def test_a_tracker_set_joins_only_where_sets_are_served() -> None:
    from posecast.tracking.sites import TrackerSet

    with pytest.raises(LayoutUnsupportedError) as e:
        _session().handle(Hello(1, token(), "r1", "A", layout=TrackerSet.parse(_SET)), time.time())
    # It said only "layout tracker sets are not served": now which option serves them.
    assert e.value.message == (
        "layout tracker sets are not served here (layouts hmd3+waist,hmd3): start the"
        " server with sites in its layouts, --layouts hmd3+waist,hmd3,sites (POSECAST_LAYOUTS)"
    )
    assert str(_set_player().layout) == _SET


def test_a_sets_frames_land_on_model_rows_and_a_lost_imu_keeps_no_acceleration() -> None:
    s = _set_player()
    out = s.handle(_sites_frame(1), time.time())
    assert isinstance(out, FrameIn)
    f = out.frame
    assert f.pos.shape == (10, 3) and f.quat.shape == (10, 4)
    assert f.pos[3].tolist() == [0, 1, 0]  # the waist's row (wire entry 4)
    assert f.pos[4].tolist() == [0.5, -9.0, 2.0]  # the left foot's acceleration
    assert not f.pos[5:].any() and (f.quat[5:, 3] == 1).all()  # absent sites
    lost = s.handle(_sites_frame(2, valid=0b10111), time.time())  # the IMU dropped out
    assert isinstance(lost, FrameIn)
    assert lost.frame.pos[4].tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    ("frame", "field"),
    [(lambda: _sites_frame(1, rows=4, valid=0b1111), "sites"), (lambda: walk_frame(1), "trackers")],
)
def test_a_sets_rows_must_match_it(frame: object, field: str) -> None:
    from posecast.errors import BadFieldError

    s = _set_player()
    with pytest.raises(BadFieldError) as e:
        s.handle(frame(), time.time())  # type: ignore[operator]
    assert e.value.field == field and not e.value.fatal
    # A refused frame counts for nothing: the same seq, put right, is taken.
    assert s.last_seq is None and s.frames == 0
    assert isinstance(s.handle(_sites_frame(1), time.time()), FrameIn)


def test_a_named_layout_may_not_send_sites() -> None:
    from posecast.errors import BadFieldError

    with pytest.raises(BadFieldError) as e:
        _joined().handle(_sites_frame(1), time.time())
    assert e.value.field == "sites"


def test_a_sets_tpose_calibrates_every_present_site() -> None:
    s = _set_player()
    pos = np.array([[0, 1.6, 0], [0.8, 1.4, 0], [-0.8, 1.4, 0], [0, 0.1, 0], [0, 1, 0]], float)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    out = s.handle(Calibrate(pos=pos, quat=quat, sites=True), time.time())
    assert isinstance(out, CalibrateIn)
    offsets = np.array(out.calibration.rot_offsets)
    assert offsets.shape == (10, 4) and np.allclose(offsets[:, 3], 1.0)  # facing +Z already
    with pytest.raises(CalibrationFailedError):
        s.handle(Calibrate(pos=pos * 3.0, quat=quat, sites=True), time.time())
    from posecast.errors import BadFieldError

    with pytest.raises(BadFieldError):
        s.handle(Calibrate(pos=pos[:4], quat=quat[:4]), time.time())  # trackers, not sites


def test_frames_that_arrive_together_after_a_stall_are_no_burst_of_the_players() -> None:
    """Three seconds of 60 Hz frames that waited in the kernel while the server was busy
    reach the session at one instant: judged on their own times, none is over the rate.
    The same frames claiming one instant (t repeated) are judged on arrival: the bucket's
    burst, then RATE_LIMITED."""
    s = _joined(max_rate_hz=120, rate_burst=30)
    flat = _joined(max_rate_hz=120, rate_burst=30)
    for seq in range(60):  # a second at 60 Hz, on time
        s.handle(walk_frame(seq, t=seq / 60), 1000.0 + seq / 60)
        flat.handle(walk_frame(seq, t=5.0), 1000.0 + seq / 60)
    now, limited = 1004.0, 0  # then a 3 s stall, and its frames at once
    for seq in range(60, 240):
        assert isinstance(s.handle(walk_frame(seq, t=seq / 60), now), FrameIn)
        try:
            flat.handle(walk_frame(seq, t=5.0), now)
        except RateLimitedError:
            limited += 1
    assert limited == 180 - 30


def test_a_frame_clock_set_ahead_restarts_the_drift_estimate() -> None:
    s = _joined()
    for seq in range(600):
        s.handle(walk_frame(seq, t=seq / 60), 1000.0 + seq / 60)
    out = s.handle(walk_frame(600, t=1e6), 1010.0)
    assert isinstance(out, FrameIn) and out.odd_time == "jump"
    for seq in range(601, 1200):
        s.handle(walk_frame(seq, t=1e6 + (seq - 600) / 60), 1000.0 + seq / 60)
    assert s.clock.drift_ppm is None or abs(s.clock.drift_ppm) < 10.0
