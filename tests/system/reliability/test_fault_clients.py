"""Client faults against a real ``posecast serve``: a client that vanishes without a
close frame, and clients that stop reading their socket.

Healthy clients are the reference: every one of them must keep getting every pose
the others get (none lost), at the tick rate, while the faulty ones come and go.
"""

from __future__ import annotations

import asyncio
import statistics
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable, Iterator

import pytest

from posecast.online.protocol.messages import Presence, Welcome
from tests.online.conftest import token, walk_frame
from tests.online.wsclient import Client
from tests.system.reliability.fault_helpers import (
    TICK_HZ,
    RssSampler,
    ServerProc,
    SilentReader,
    abort_with_reset,
    fmt,
    is_,
    max_gap_s,
    pose_of,
    rates_hz,
    report,
    seqs_in,
    server_gap_s,
)

pytestmark = pytest.mark.timeout(120)
# Server defaults (online/config.py) the assertions are about.
SLOW_CONSUMER_S = 2.0  # slow_consumer_s: a writer undrained this long is cut off
SOCKET_SNDBUF_BYTES = 65536  # socket_sndbuf_bytes: the kernel's share of the backlog


@pytest.fixture
def server() -> Iterator[ServerProc]:
    srv = ServerProc()
    try:
        yield srv
    finally:
        srv.close()


async def player(port: int, name: str, seed: int, room: str = "r1") -> Client:
    cl = await Client.open(port)
    assert isinstance(await cl.hello(token(room, name), room=room, name=name.upper()), Welcome)
    cl.stream(seed=seed)
    return cl


def assert_none_lost(
    clients: dict[str, Client], t0: float, t1: float, superseded: float = 0.0
) -> tuple[int, int]:
    """Every healthy client got the same ``(player, seq)`` poses in server time
    ``[t0, t1]``, except poses the server *superseded* in a client's outbox (a newer
    pose of the same avatar replaced one its writer had not sent yet: latest-wins,
    docs/broadcast.md, counted in ``posecast_poses_superseded_total``). Nothing may go
    missing without being counted there. Returns (poses per client, missing)."""
    seen = {name: seqs_in(cl.poses(), t0, t1) for name, cl in clients.items()}
    union = set().union(*seen.values())
    lost = {name: len(union - s) for name, s in seen.items()}
    missing = sum(lost.values())
    # The superseded count is server-wide (non-reading clients supersede plenty), so
    # the real guard is the share: at most 1 % of a healthy client's poses.
    assert max(lost.values()) <= 0.01 * len(union), f"lost: {lost} of {len(union)}"
    assert missing <= superseded, (
        f"poses lost by healthy clients: {lost} of {len(union)}, only {superseded:.0f} superseded"
    )
    return len(union), missing


# A player in its own process: the SDK streaming a walk until it is SIGKILLed.
_SDK_PLAYER = textwrap.dedent(
    """
    import asyncio, sys
    import posecast_client as pc

    async def main() -> None:
        url, tok = sys.argv[1], sys.argv[2]
        client = await pc.connect(url, tok, reconnect=False)
        await client.join("r1", "DOOMED")
        print("joined", flush=True)
        await client.stream(pc.WalkSource(seconds=60.0, loop=True))

    asyncio.run(main())
    """
)


def test_a_vanished_client_leaves_the_room_at_once(server: ServerProc) -> None:
    """TCP reset without a close frame (``SO_LINGER`` 0), and a SIGKILLed client
    process: the room hears ``leave`` as soon as the kernel says the socket is gone;
    the healthy players lose nothing meanwhile."""

    async def scenario() -> None:
        ann, bob = await player(server.port, "ann", 0), await player(server.port, "bob", 1)
        vic = await player(server.port, "vic", 2)
        proc = subprocess.Popen(
            [sys.executable, "-c", _SDK_PLAYER, server.url, token("r1", "doomed")],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            assert (await asyncio.to_thread(proc.stdout.readline)).strip() == "joined"
            for who in ("vic", "doomed"):
                await ann.wait_for(pose_of(who), 10)

            await asyncio.sleep(1.0)
            t_start = ann.poses()[-1].t
            took = {}
            vanishings: list[tuple[str, Callable[[], None]]] = [
                ("vic", lambda: abort_with_reset(vic.ws)),
                ("doomed", proc.kill),
            ]
            for who, vanish in vanishings:
                start = len(ann.messages)
                t0 = time.monotonic()
                vanish()
                leave = Presence("leave", "r1", who, who.upper())
                await ann.wait_for(is_(leave), 10, start)
                took[who] = time.monotonic() - t0
                await bob.wait_for(is_(leave), 2)
            await asyncio.sleep(1.0)
            t_end = ann.poses()[-1].t
            await asyncio.sleep(0.2)
            window = (t_start - 0.5, t_end - 0.1)  # the vanishings and a while around them
            per_client, _ = assert_none_lost({"ann": ann, "bob": bob}, *window)
            rates = rates_hz(ann.poses("bob"), *window)
        finally:
            proc.kill()
            proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()
        report(
            "vanished client",
            leave_after_rst_s=f"{took['vic']:.3f}",
            leave_after_sigkill_s=f"{took['doomed']:.3f}",
            healthy_poses_compared=per_client,
            healthy_lost=0,
            bob_rate_hz=fmt(rates),
        )
        # The kernel reports a reset at once; the tick (1/60 s) and the loop's
        # scheduling are the only delays. One second is the bound on a loaded CI box.
        assert max(took.values()) < 1.0, took
        assert min(rates) >= 0.5 * TICK_HZ, rates
        for cl in (ann, bob):
            await cl.close()
        await vic.close()

    asyncio.run(scenario())


def test_clients_that_never_read_are_cut_off_and_block_nobody(server: ServerProc) -> None:
    """Four players complete the handshake, send ``hello`` and frames, and never read.
    The tick, the healthy players' pose rate and the server's memory hold; each
    silent reader is cut off ``slow_consumer_s`` after its backlog stopped draining."""
    silent_n = 4

    async def scenario() -> None:
        rss = RssSampler(server.proc.pid)
        healthy = {n: await player(server.port, n, seed) for seed, n in enumerate("abc")}
        await healthy["a"].wait_for(pose_of("c"), 10)
        await asyncio.sleep(1.5)
        t_base = time.monotonic()
        base_rss = statistics.median(rss.between(t_base - 1.0, t_base))
        frames_before = server.metric("posecast_frames_total")
        superseded_before = server.metric("posecast_poses_superseded_total")

        readers = [
            SilentReader(server.port, token("r1", f"s{i}"), "r1", f"S{i}") for i in range(silent_n)
        ]
        t_start_server = healthy["a"].poses()[-1].t
        cut_at: dict[int, float] = {}
        seq = 0
        deadline = time.monotonic() + 30
        while len(cut_at) < silent_n and time.monotonic() < deadline:
            for i, r in enumerate(readers):
                if i in cut_at:
                    continue
                if r.reset_by_server():
                    cut_at[i] = time.monotonic() - r.hello_at
                else:
                    r.send_nowait(walk_frame(seq, seed=10 + i))  # they talk, but never listen
            seq += 1
            await asyncio.sleep(1 / TICK_HZ)
        t_cut = time.monotonic()
        await asyncio.sleep(1.0)  # and after they are gone
        t_end_server = healthy["a"].poses()[-1].t
        rss.stop()
        for r in readers:
            r.close()

        during = rss.between(t_base, t_cut)
        after = rss.between(t_cut, time.monotonic())
        superseded = server.metric("posecast_poses_superseded_total") - superseded_before
        per_client, missing = assert_none_lost(healthy, t_start_server, t_end_server, superseded)
        rates = {n: rates_hz(healthy["a"].poses(n), t_start_server, t_end_server) for n in healthy}
        gaps = {n: max_gap_s(healthy["b"].poses(n)) for n in healthy}
        by_server = {n: server_gap_s(healthy["b"].poses(n), healthy[n].sent_at) for n in healthy}
        silent_seen = {p.player for p in healthy["a"].poses() if p.player.startswith("s")}
        slow_errors = server.metric('posecast_errors_total{code="SLOW_CONSUMER"}')
        report(
            "silent readers",
            cut_off_after_hello_s=fmt(sorted(cut_at.values()), 2),
            rss_base_mib=f"{base_rss / 1024:.1f}",
            rss_peak_mib=f"{max(during) / 1024:.1f}",
            rss_after_mib=f"{max(after) / 1024:.1f}",
            healthy_rate_min_hz=f"{min(min(r) for r in rates.values()):.0f}",
            healthy_rate_a_hz=fmt(rates["a"], 0),
            max_pose_gap_s=fmt(gaps.values(), 3),
            max_pose_gap_by_server_s=fmt(by_server.values(), 3),
            healthy_poses_compared=per_client,
            healthy_missing_superseded=missing,
            frames_accepted=int(server.metric("posecast_frames_total") - frames_before),
            slow_consumer_errors=int(slow_errors),
        )
        assert len(cut_at) == silent_n, f"only {len(cut_at)} of {silent_n} cut off in 30 s"
        # Not before the limit: a writer must be stuck slow_consumer_s first.
        assert min(cut_at.values()) >= SLOW_CONSUMER_S, cut_at
        assert silent_seen, "the silent players' own frames never made poses"
        # Memory: a stuck client holds its outbox (one pose slot per avatar) plus the
        # transport's bounded write buffer, not a backlog. 4 clients: far below 16 MiB.
        assert max(during) - base_rss < 16 * 1024, (base_rss, max(during))
        # The healthy players never noticed: no window below half the tick rate, no
        # tick gap of more than a few ticks.
        assert all(min(r) >= 0.5 * TICK_HZ for r in rates.values()), rates
        assert max(by_server.values()) < 0.25, (by_server, gaps)  # the senders' stalls aside
        assert healthy["a"].ws.state.name == "OPEN"
        for cl in healthy.values():
            await cl.close()

    asyncio.run(scenario())
