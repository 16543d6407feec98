"""End to end (posecast.online.shell.app): a real server on loopback, real WebSocket
clients, the real ONNX engine (8 samples). Each test runs one asyncio scenario. At the
end, without a socket: the shell frames outgoing messages itself (``binary_frames``),
byte for byte what websockets writes."""

from __future__ import annotations

import asyncio
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Coroutine
from typing import Any

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus
from websockets.frames import Frame, Opcode
from websockets.protocol import Protocol, Side, State
from websockets.streams import StreamReader

from posecast.online.protocol.messages import Bye, Error, Kick, Presence, Welcome
from posecast.online.shell.app import binary_frames
from tests.online.conftest import make_cfg, token, walk_frame
from tests.online.wsclient import Client, Factory, serving

pytestmark = pytest.mark.timeout(30)


def run(coro: Coroutine[Any, Any, None]) -> None:
    asyncio.run(coro)


def test_rooms_see_their_own_players_and_nothing_else(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(lookahead=2), engine_factory) as server:
            a, b, c = [await Client.open(server.port) for _ in range(3)]
            assert isinstance(await a.hello(token("r1", "a")), Welcome)
            assert isinstance(await b.hello(token("r1", "b")), Welcome)
            assert isinstance(await c.hello(token("r2", "c"), room="r2"), Welcome)
            for i, cl in enumerate((a, b, c)):
                cl.stream(seed=i)
            # Wait for the poses themselves (how long 20 take depends on the machine's load).
            await b.wait_for(lambda m: len(b.poses("a")) >= 20, timeout=20.0)
            await a.wait_for(lambda m: len(a.poses("b")) >= 20, timeout=20.0)
            assert {p.player for p in a.poses()} == {"a", "b"}  # its own pose comes back too
            assert {p.player for p in b.poses()} == {"a", "b"}
            assert {p.player for p in c.poses()} == {"c"}
            assert not [m for m in c.messages if isinstance(m, Presence)]
            seqs = [p.seq for p in b.poses("a")]
            assert seqs == sorted(seqs) and len(seqs) >= 20
            assert server.metrics.value("posecast_players") == 3
            assert server.metrics.value("posecast_rooms") == 2
            # The tick's poses went out from _flush itself, not through a woken writer.
            assert server.inline_writes >= 20
            for cl in (a, b, c):
                await cl.close()

    run(scenario())


def test_welcome_lookahead_frames_is_the_delay_the_poses_carry(engine_factory: Factory) -> None:
    """The welcome says how many ticks a pose lags its frame: none by default, whatever
    the look-ahead (a transition's head start), tau with the paper's delayed emission."""

    async def welcome(**cfg: Any) -> Welcome:
        async with serving(make_cfg(**cfg), engine_factory) as server:
            assert server.cfg.engine_config().delay == server.cfg.delay_frames
            cl = await Client.open(server.port)
            w = await cl.hello(token("r1", "a"))
            await cl.close()
            assert isinstance(w, Welcome)
            return w

    async def scenario() -> None:
        assert (await welcome(lookahead=10)).lookahead_frames == 0
        assert (await welcome(lookahead=3, delayed_emission=True)).lookahead_frames == 3

    run(scenario())


def test_auth_failures_are_refused_with_their_codes(engine_factory: Factory) -> None:
    async def refused(port: int, tok: str, room: str = "r1") -> Error:
        cl = await Client.open(port)
        err = await cl.hello(tok, room=room)
        assert isinstance(err, Error) and err.fatal
        await asyncio.wait_for(cl.closed.wait(), 2)
        return err

    async def scenario() -> None:
        async with serving(make_cfg(token_leeway_s=0.5), engine_factory) as server:
            port = server.port
            forged = token()[:-4] + "AAAA"
            assert (await refused(port, forged)).code == "UNAUTHENTICATED"
            assert (await refused(port, "not-a-token")).code == "UNAUTHENTICATED"
            expired = token(ttl_s=1)
            await asyncio.sleep(1.6)
            assert (await refused(port, expired)).code == "TOKEN_EXPIRED"
            assert (await refused(port, token(room="r2"), room="r1")).code == "FORBIDDEN"

            spec = await Client.open(port)
            assert isinstance(await spec.hello(token(role="spectator", player="s")), Welcome)
            await spec.send(walk_frame(0))
            err = await spec.error()
            assert (err.code, err.fatal) == ("FORBIDDEN", False)
            await spec.send(Kick("x"))
            assert (await spec.error(start=len(spec.messages) - 1)).code == "FORBIDDEN"
            assert not spec.closed.is_set()

            tok = token(player="once")
            first = await Client.open(port)
            assert isinstance(await first.hello(tok), Welcome)
            await first.send(Bye("leaving"))
            await first.wait_for(lambda m: isinstance(m, Bye))
            assert (await refused(port, tok)).code == "UNAUTHENTICATED"  # replay after bye
            errors = server.metrics.value("posecast_errors_total", {"code": "UNAUTHENTICATED"})
            assert errors == 3
            await spec.close()

    run(scenario())


def test_transport_rules(engine_factory: Factory) -> None:
    """Frame before hello: NOT_JOINED, 1008. Text message: 1003. No subprotocol: 400."""

    async def scenario() -> None:
        async with serving(make_cfg(), engine_factory) as server:
            cl = await Client.open(server.port)
            await cl.send(walk_frame(0))
            err = await cl.error()
            assert (err.code, err.fatal) == ("NOT_JOINED", True)
            await asyncio.wait_for(cl.closed.wait(), 2)
            assert (cl.ws.close_code, cl.ws.close_reason) == (1008, "NOT_JOINED")

            text = await Client.open(server.port)
            await text.hello(token())
            await text.ws.send('{"type": "ping", "t0": 1}')
            await asyncio.wait_for(text.closed.wait(), 2)
            assert text.ws.close_code == 1003

            with pytest.raises(InvalidStatus) as e:
                await connect(f"ws://127.0.0.1:{server.port}/")
            assert e.value.response.status_code == 400

    run(scenario())


def test_reconnect_with_the_same_player_id(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(lookahead=2), engine_factory) as server:
            tok = token(player="a")
            a1, b = await Client.open(server.port), await Client.open(server.port)
            await a1.hello(tok)
            await b.hello(token(player="b"))
            a1.stream(seq0=0)
            await b.wait_for(lambda m: getattr(m, "player", "") == "a")
            a1.ws.transport.abort()  # the network drops, no bye
            await asyncio.sleep(0.1)
            a2 = await Client.open(server.port)
            assert isinstance(await a2.hello(tok), Welcome)  # same token, same id
            mark = len(b.messages)
            a2.stream(seq0=0)  # a new connection may start its seq afresh
            await b.wait_for(lambda m: getattr(m, "player", "") == "a", start=mark)
            await a2.wait_for(lambda m: getattr(m, "player", "") == "a")

            a3 = await Client.open(server.port)  # joins while a2 is still connected
            assert isinstance(await a3.hello(tok), Welcome)
            err = await a2.error()
            assert (err.code, err.fatal) == ("REPLACED", True)
            await asyncio.wait_for(a2.closed.wait(), 2)
            leaves = [m for m in b.messages if isinstance(m, Presence) and m.event == "leave"]
            assert len(leaves) == 1  # the drop; the takeover is silent
            for cl in (b, a3):
                await cl.close()

    run(scenario())


def test_rate_limit(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(max_rate_hz=60, rate_burst=10), engine_factory) as server:
            cl = await Client.open(server.port)
            await cl.hello(token())
            for seq in range(60):  # a burst of a second's frames at once
                await cl.send(walk_frame(seq))
            err = await cl.error()
            assert (err.code, err.fatal) == ("RATE_LIMITED", False)

            def dropped() -> float:
                return server.metrics.value("posecast_frames_dropped_total", {"reason": "rate"})

            # The read budget hands the burst to the session over about 0.2 s (frames
            # beyond the tokens saved before hello wait): count once all 60 are handled.
            deadline = asyncio.get_running_loop().time() + 5.0
            while server.metrics.value("posecast_frames_total") + dropped() < 60:
                assert asyncio.get_running_loop().time() < deadline
                await asyncio.sleep(0.02)
            # 10 of burst, plus what refills over the frames' own times (judged on `t`)
            assert 30 <= dropped() <= 50
            await cl.send(walk_frame(1000))  # still connected; frames flow again later
            await asyncio.sleep(0.2)
            await cl.wait_for(lambda m: m.TYPE == "pose")
            await cl.close()

    run(scenario())


def test_slow_consumer_is_cut_off_and_nobody_waits(engine_factory: Factory) -> None:
    async def scenario() -> None:
        cfg = make_cfg(lookahead=0, slow_consumer_s=0.5, socket_sndbuf_bytes=4096)
        async with serving(cfg, engine_factory) as server:
            fast = await Client.open(server.port)
            await fast.hello(token(player="fast"))
            fast.stream()
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.connect(("127.0.0.1", server.port))
            slow = await Client.open(server.port, read=False, sock=sock, max_queue=1)
            await slow.send(token_hello(token(player="slow")))
            players = [await Client.open(server.port) for _ in range(6)]  # lots of poses
            for i, p in enumerate(players):
                await p.hello(token(player=f"p{i}"))
                p.stream(seed=i)
            t0 = time.monotonic()
            while server.metrics.value("posecast_errors_total", {"code": "SLOW_CONSUMER"}) < 1:
                assert time.monotonic() - t0 < 10, "the slow client was never cut off"
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.2)
            assert "slow" not in server.hub.connections.by_player
            mark = len(fast.messages)
            await asyncio.sleep(0.3)  # the fast client's stream went on throughout
            assert len(fast.poses("fast")) > 20
            assert any(m.TYPE == "pose" for m in fast.messages[mark:])
            for cl in (fast, *players):
                await cl.close()
            slow.ws.transport.abort()
            await asyncio.wait_for(slow.ws.wait_closed(), 2)

    run(scenario())


def token_hello(tok: str) -> bytes:
    from posecast.online.protocol import encode
    from posecast.online.protocol.messages import Hello

    return encode(Hello(1, tok, "r1", "Slow"))


def test_stale_and_active_presence(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(), engine_factory) as server:
            a, b = await Client.open(server.port), await Client.open(server.port)
            await a.hello(token(player="a"))
            await b.hello(token(player="b"))
            for seq in range(5):
                await a.send(walk_frame(seq))
            # 30 ticks without frames (0.5 s) mark a stale; a frame makes it active.
            await b.wait_for(lambda m: m == Presence("stale", "r1", "a", "Ann"), 3)
            await a.send(walk_frame(100))
            await b.wait_for(lambda m: m == Presence("active", "r1", "a", "Ann"), 3)
            for cl in (a, b):
                await cl.close()

    run(scenario())


def test_backend_watches_rooms_and_kicks(engine_factory: Factory) -> None:
    async def scenario() -> None:
        async with serving(make_cfg(lookahead=1), engine_factory) as server:
            a, b = await Client.open(server.port), await Client.open(server.port)
            await a.hello(token("r1", "a"))
            await b.hello(token("r2", "b"), room="r2")
            a.stream(seed=0)
            b.stream(seed=1)
            be = await Client.open(server.port)
            tok = token("r1", "be", role="backend", rooms=("r2",))
            assert isinstance(await be.hello(tok, watch=("r2",)), Welcome)
            await be.wait_for(lambda m: getattr(m, "player", "") == "b" and m.TYPE == "pose")
            await be.wait_for(lambda m: getattr(m, "player", "") == "a" and m.TYPE == "pose")
            await be.send(Kick("b", "bye bye"))
            err = await b.error()
            assert (err.code, err.message, err.fatal) == ("KICKED", "bye bye", True)
            await be.wait_for(lambda m: isinstance(m, Presence) and m.event == "leave")
            await be.send(Kick("b"))
            assert (await be.error()).code == "NOT_FOUND"
            for cl in (a, be):
                await cl.close()

    run(scenario())


def test_http_endpoints_and_connection_limits(engine_factory: Factory) -> None:
    def get(url: str) -> tuple[int, str]:
        try:
            with urllib.request.urlopen(url, timeout=5) as r:
                return r.status, r.read().decode()
        except urllib.error.HTTPError as e:
            return e.code, ""

    async def scenario() -> None:
        async with serving(make_cfg(conn_per_ip_per_min=2), engine_factory) as server:
            base = f"http://127.0.0.1:{server.port}"
            assert (await asyncio.to_thread(get, base + "/healthz"))[0] == 200
            assert (await asyncio.to_thread(get, base + "/readyz"))[0] == 200
            a = await Client.open(server.port)
            await a.hello(token())
            await a.send(b"\xc1")
            await a.error()
            status, text = await asyncio.to_thread(get, base + "/metrics")
            assert status == 200 and 'posecast_errors_total{code="MALFORMED"} 1.0' in text
            assert "posecast_tick_seconds_bucket" in text
            # what the engine runs on: the ONNX engine here, fp32
            info = [ln for ln in text.splitlines() if ln.startswith("posecast_engine_info{")]
            assert len(info) == 1 and info[0].endswith(" 1.0"), info
            assert 'backend="onnx",isa="",layout="hmd3+waist",precision="fp32"' in info[0]
            await Client.open(server.port)
            with pytest.raises(InvalidStatus) as e:
                await Client.open(server.port)  # the third attempt this minute
            assert e.value.response.status_code == 429
            server.ready = False
            assert (await asyncio.to_thread(get, base + "/readyz"))[0] == 503

    run(scenario())


def test_port_zero_is_one_port_on_every_address(engine_factory: Factory) -> None:
    """``--host "" --port 0`` listens on every IPv4 and IPv6 interface; each address
    got its own ephemeral port, and the port the server names reached one of them."""

    async def scenario() -> None:
        async with serving(make_cfg(host=""), engine_factory) as server:
            assert server._server is not None
            ports = {sock.getsockname()[1] for sock in server._server.sockets}
            assert ports == {server.port}
            families = {sock.family for sock in server._server.sockets}
            for family, host in ((socket.AF_INET, "127.0.0.1"), (socket.AF_INET6, "::1")):
                if family in families:  # the named port answers on each family it serves
                    with socket.socket(family) as probe:
                        probe.settimeout(5)
                        probe.connect((host, server.port))

    run(scenario())


SIZES = (0, 1, 125, 126, 127, 300, 65535, 65536, 70000)


def _websockets_bytes(batch: list[bytes]) -> bytes:
    proto = Protocol(Side.SERVER, state=State.OPEN, max_size=None)
    for data in batch:
        proto.send_binary(data)
    return b"".join(proto.data_to_send())


def test_each_length_class_frames_as_websockets_does() -> None:
    for n in SIZES:
        data = bytes(range(256)) * (n // 256) + bytes(n % 256)
        assert binary_frames([data]) == _websockets_bytes([data]), n


def test_a_batch_is_the_frames_back_to_back_and_parses_as_messages() -> None:
    batch = [bytes([i % 251]) * n for i, n in enumerate(SIZES)]
    wire = binary_frames(batch)
    assert wire == _websockets_bytes(batch)
    reader = StreamReader()
    reader.feed_data(wire)
    reader.feed_eof()
    parser = Frame.parse(reader.read_exact, mask=False, max_size=None)
    got = []
    for _ in batch:
        try:
            next(parser)
        except StopIteration as done:
            frame = done.value
        assert frame.fin and frame.opcode is Opcode.BINARY
        got.append(bytes(frame.data))
        parser = Frame.parse(reader.read_exact, mask=False, max_size=None)
    assert got == batch
    assert binary_frames([]) == b""
