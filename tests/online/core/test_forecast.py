"""The forecast on the wire (v2): ``hello.forecast_ms`` and ``forecast`` set each
receiving client's horizon, in whole ticks; out of range is ``OUT_OF_RANGE``
(counted, the setting kept); the router asks the engine thread for the horizons of
each room's clients and gives each client the poses of its own horizon."""

from __future__ import annotations

import msgpack
import pytest

from posecast.online.core.tick import TickOutput
from posecast.online.protocol import records
from posecast.online.protocol.messages import Forecast, Hello, Poses, Welcome
from posecast.testing.poses import pose_out
from tests.online.conftest import token
from tests.online.core.harness import Harness


def _join_v2(
    h: Harness, player: str, room: str = "r1", role: str = "player", **hello: float
) -> int:
    conn = h.hub.connect("10.0.0.1", h.now, 2)
    h.versions[conn] = 2
    tok = token(room=room, player=player, role=role)
    h.send(conn, Hello(2, tok, room, player.upper(), **hello))  # type: ignore[arg-type]
    return conn


def _welcome(h: Harness, conn: int) -> Welcome:
    got = [m for m in h.inbox(conn) if isinstance(m, Welcome)]
    assert len(got) == 1
    return got[0]


@pytest.mark.parametrize(("ms", "ticks"), [(67.0, 4), (33.0, 2), (100.0, 6), (5.0, 0)])
def test_hello_asks_for_a_horizon_in_whole_ticks(ms: float, ticks: int) -> None:
    h = Harness()
    conn = _join_v2(h, "a", forecast_ms=ms)
    w = _welcome(h, conn)
    assert w.forecast_ms == (pytest.approx(ticks * 1000 / 60) if ticks else None)
    assert h.hub.router.horizons() == ({"a": frozenset({ticks})} if ticks else {})


def test_out_of_range_is_refused_counted_and_changes_nothing() -> None:
    h = Harness()
    conn = _join_v2(h, "a", forecast_ms=67.0)
    h.inbox(conn)
    for bad in (150.0, -1.0, float("nan"), float("inf")):
        h.hub.receive(conn, msgpack.packb({"type": "forecast", "ms": bad}), h.now)
    assert h.codes(conn) == ["OUT_OF_RANGE"] * 4
    assert h.hub.metrics.value("posecast_errors_total", {"code": "OUT_OF_RANGE"}) == 4
    assert h.hub.router.horizons() == {"a": frozenset({4})}  # as it was
    assert h.hub.joined(conn)
    # at join, out of range refuses the hello (as any bad hello field)
    late = h.hub.connect("10.0.0.1", h.now, 2)
    h.versions[late] = 2
    hello = {"type": "hello", "version": 2, "token": token(room="r1", player="b"),
             "room": "r1", "name": "B", "forecast_ms": 101.0}  # fmt: skip
    h.hub.receive(late, msgpack.packb(hello), h.now)
    assert h.codes(late) == ["OUT_OF_RANGE"] and not h.hub.joined(late)


def test_v1_has_no_forecast() -> None:
    h = Harness()
    conn = h.join("a")
    h.inbox(conn)
    h.hub.receive(conn, msgpack.packb({"type": "forecast", "ms": 67.0}), h.now)
    assert h.codes(conn) == ["UNKNOWN_TYPE"]
    assert h.hub.router.horizons() == {}


def test_horizons_are_the_rooms_distinct_ones_and_go_with_their_clients() -> None:
    h = Harness()
    a, b = _join_v2(h, "a"), _join_v2(h, "b", forecast_ms=33.0)
    s = _join_v2(h, "s", role="spectator", forecast_ms=67.0)
    other = _join_v2(h, "c", room="r2")
    assert h.hub.router.horizons() == {"a": frozenset({2, 4}), "b": frozenset({2, 4})}
    h.send(s, Forecast(33.0))  # two clients at the same horizon: one forecast
    assert h.hub.router.horizons() == {"a": frozenset({2}), "b": frozenset({2})}
    h.send(other, Forecast(100.0))
    assert h.hub.router.horizons()["c"] == frozenset({6})
    h.send(other, Forecast(0.0))  # 0 turns it off
    h.hub.disconnect(b, h.now)
    assert h.hub.router.horizons() == {"a": frozenset({2})}
    h.hub.disconnect(s, h.now)
    assert h.hub.router.horizons() == {}  # nobody asks: the engine thread does nothing
    assert a


Refs = dict[int, records.Recon | None]


def _poses_t(h: Harness, conn: int, refs: Refs) -> list[tuple[float, int]]:
    """Each record's (message t, seq) that ``conn`` got, against its references."""
    out = []
    for m in h.inbox(conn):
        if isinstance(m, Poses):
            for rec in records.decode_records(m.data, refs):
                out.append((m.t, rec.recon.seq))
    return out


def test_each_client_gets_the_poses_of_its_own_horizon() -> None:
    h = Harness()
    a = _join_v2(h, "a")
    ahead = _join_v2(h, "s", role="spectator", forecast_ms=67.0)
    v1 = h.join("old", role="spectator")
    for conn in (a, ahead, v1):
        h.inbox(conn)
    base = pose_out("a", 7, t=10.0)
    fc = pose_out("a", 7, t=10.0 + 4 / 60)
    h.hub.deliver(TickOutput([base], ahead={4: {"a": fc}}), h.now)
    ref_a: Refs = dict.fromkeys(range(4))
    ref_ahead: Refs = dict.fromkeys(range(4))
    assert _poses_t(h, a, ref_a) == [(10.0, 7)]
    assert _poses_t(h, ahead, ref_ahead) == [(pytest.approx(10.0 + 4 / 60), 7)]
    v1_poses = [m for m in h.inbox(v1) if getattr(m, "TYPE", "") == "pose"]
    assert [(p.t, p.seq) for p in v1_poses] == [(10.0, 7)]  # type: ignore[attr-defined]
    # a player with no forecast made (another node's, say) goes as it is
    h.hub.deliver(TickOutput([pose_out("a", 8, t=11.0)], ahead={4: {}}), h.now)
    assert _poses_t(h, ahead, ref_ahead) == [(11.0, 8)]
