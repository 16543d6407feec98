"""``posecast serve --workers 2``: a supervisor and two serving processes on one port
(docs/scale-out.md, Workers). Real processes, real sockets, the shipped models:

* players the kernel placed on different workers meet in one room, and one scrape
  of ``/metrics`` on either worker covers both and the supervisor;
* a worker SIGKILLed while SDK players stream is restarted and counted, and every
  player gets every room-mate's poses (its own too) made within 1 s of the kill (the
  SDK reconnects on its own; times are the ticks', on this machine's monotonic clock);
* SIGTERM drains every worker's players, then the supervisor exits; SIGHUP reaches
  every worker (the key set is re-read by each).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import time
from collections import defaultdict
from pathlib import Path

import posecast_client as pc
import pytest

from posecast.online.auth.keys import generate
from posecast.online.protocol.messages import Bye, Welcome
from posecast.online.shell.app import WORKER_HEADER
from posecast.testing.serve import ServeProcess, metric_sum, process_tree
from tests.online.conftest import SECRET, token
from tests.online.wsclient import Client

pytestmark = pytest.mark.timeout(120)
RESUME_S = 1.0  # issue 39: a dead worker's players resume within this


def node(*flags: str) -> ServeProcess:
    srv = ServeProcess(*flags, secret=SECRET, workers=2)
    srv.wait_ready()
    return srv


async def placed(port: int, tries: int = 60) -> dict[str, Client]:
    """One connection on each worker: connect until the kernel has put one on each
    (it spreads connections by their address hash), closing the spares."""
    got: dict[str, Client] = {}
    for _ in range(tries):
        cl = await Client.open(port)
        assert cl.ws.response is not None
        worker = cl.ws.response.headers[WORKER_HEADER]
        if worker in got:
            await cl.close()
        else:
            got[worker] = cl
        if len(got) == 2:
            return got
    raise AssertionError(f"{tries} connections all landed on worker {list(got)}")


def worker_pids(srv: ServeProcess) -> dict[int, int]:
    """Worker index -> pid, from the supervisor's children's command lines."""
    out = {}
    for pid in process_tree(srv.pid)[1:]:
        with contextlib.suppress(OSError):
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            if b"posecast.online.shell.worker" in argv:
                out[int(argv[argv.index(b"posecast.online.shell.worker") + 1])] = pid
    return out


def test_players_on_two_workers_meet_in_one_room_and_one_scrape_covers_the_node() -> None:
    with node() as srv:

        async def scenario() -> None:
            clients = await placed(srv.port)
            a, b = clients["0"], clients["1"]
            assert isinstance(await a.hello(token("r1", "a"), name="A"), Welcome)
            assert isinstance(await b.hello(token("r1", "b"), name="B"), Welcome)
            a.stream(seed=0)
            b.stream(seed=1)
            await a.wait_for(lambda m: len(a.poses("b")) >= 20, timeout=20.0)
            await b.wait_for(lambda m: len(b.poses("a")) >= 20, timeout=20.0)
            seqs = [p.seq for p in a.poses("b")]
            assert seqs == sorted(seqs)
            m = srv.metrics()
            for w in ("0", "1"):
                assert m[f'posecast_players{{worker="{w}"}}'] == 1
                assert m[f'posecast_remote_players{{worker="{w}"}}'] == 1
                assert m[f'posecast_ticks_total{{worker="{w}"}}'] > 0
            assert m['posecast_workers{worker="supervisor"}'] == 2
            assert m['posecast_worker_restarts_total{worker="supervisor"}'] == 0
            assert m['posecast_relay_forwarded_total{worker="supervisor"}'] > 0
            for cl in (a, b):
                await cl.close()

        asyncio.run(scenario())
        for _ in range(4):
            assert srv.http("/readyz") == (200, "ready\n")


def test_a_killed_worker_is_restarted_and_its_players_resume_within_a_second() -> None:
    """Six SDK players stream in one room; the worker holding most of them is
    SIGKILLed. The supervisor restarts it (counted); its players reconnect by
    themselves to the worker still listening, and every player sees every room-mate's
    poses again within ``RESUME_S`` of the kill."""
    names = [f"p{i}" for i in range(6)]
    with node() as srv:

        async def scenario() -> dict[str, float]:
            seen: dict[str, dict[str, list[float]]] = {n: defaultdict(list) for n in names}
            clients: dict[str, pc.Client] = {}
            welcomed: dict[str, float] = {}
            tasks = []

            async def collect(name: str, cl: pc.Client) -> None:
                async for ev in cl.events():
                    if isinstance(ev, pc.Pose):  # stamped with the server's tick time
                        seen[name][ev.player].append(ev.t)
                    elif isinstance(ev, pc.Welcome):
                        welcomed[name] = time.monotonic()

            for i, name in enumerate(names):
                cl = await pc.connect(srv.url, token("r1", name))
                await cl.join("r1", name.upper())
                clients[name] = cl
                src = pc.WalkSource(seconds=30.0, seed=i, loop=True)
                tasks += [
                    asyncio.create_task(cl.stream(src)),
                    asyncio.create_task(collect(name, cl)),
                ]
            deadline = time.monotonic() + 30
            while not all(len(seen[n][q]) >= 10 for n in names for q in names):
                assert time.monotonic() < deadline, "the room never filled"
                await asyncio.sleep(0.05)
            per = {w: metric_sum(srv.metrics(), "posecast_players", worker=str(w)) for w in (0, 1)}
            victim = max(per, key=lambda w: per[w])
            pid = worker_pids(srv)[victim]
            t_kill = time.monotonic()
            os.kill(pid, signal.SIGKILL)
            await asyncio.sleep(3.0)
            # For each pair, how long after the kill a player got a room-mate's (or its
            # own) pose made after the kill: the ticks' own times (the server's clock is
            # this machine's monotonic clock), so this process's lag does not count.
            gaps = {}
            for n in names:
                for q in names:
                    after = [t for t in seen[n][q] if t > t_kill]
                    assert after, (n, q)
                    gaps[f"{n}<-{q}"] = min(after) - t_kill
            reconnects = sum(cl.stats.reconnects for cl in clients.values())
            assert reconnects == per[victim], (reconnects, per)
            rejoined = {k: round(v - t_kill, 3) for k, v in welcomed.items()}
            print(f"players per worker {per}; rejoined after {rejoined} s")
            for t in tasks:
                t.cancel()
            for cl in clients.values():
                await cl.close()
            return gaps

        gaps = asyncio.run(scenario())
        worst = max(gaps, key=lambda k: gaps[k])
        print(f"poses again after the kill within {gaps[worst]:.3f} s ({worst})")
        assert gaps[worst] < RESUME_S, gaps
        deadline = time.monotonic() + 30
        while True:  # the restarted worker serves again, and the restart is counted
            m = srv.metrics()
            workers = {k for k in m if k.startswith("posecast_ticks_total{")}
            if len(workers) == 2 and m['posecast_workers{worker="supervisor"}'] == 2:
                break
            assert time.monotonic() < deadline, m
            time.sleep(0.2)
        assert m['posecast_worker_restarts_total{worker="supervisor"}'] == 1
        assert set(worker_pids(srv)) == {0, 1}


def test_sigterm_drains_every_worker_and_the_supervisor_exits_after_them() -> None:
    srv = node()
    try:

        async def scenario() -> list[Client]:
            clients = await placed(srv.port)
            for w, cl in clients.items():
                assert isinstance(await cl.hello(token("r1", f"p{w}")), Welcome)
            srv.proc.send_signal(signal.SIGTERM)
            for cl in clients.values():
                await asyncio.wait_for(cl.closed.wait(), 15)
            return list(clients.values())

        clients = asyncio.run(scenario())
        for cl in clients:
            byes = [m for m in cl.messages if isinstance(m, Bye)]
            assert len(byes) == 1 and byes[0].reason, cl.messages
        assert srv.proc.wait(timeout=20) == 0
        assert all(not Path(f"/proc/{p}").exists() for p in process_tree(srv.pid)[1:])
    finally:
        srv.stop()


def test_sighup_reaches_every_worker(tmp_path: Path) -> None:
    _, public = generate("ES256", "k1")
    keys = tmp_path / "keys.json"
    keys.write_text(json.dumps({"keys": [public]}))
    with node("--token-keys-file", str(keys)) as srv:
        reloads = 'posecast_token_key_reloads_total{result="ok",worker="%s"}'
        srv.proc.send_signal(signal.SIGHUP)
        deadline = time.monotonic() + 10
        while True:
            m = srv.metrics()
            if all(m.get(reloads % w) == 1 for w in ("0", "1")):
                break
            assert time.monotonic() < deadline, m
            time.sleep(0.1)


def test_auto_runs_a_worker_per_cpu_each_kept_to_its_own() -> None:
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        pytest.skip("one CPU: auto runs the single process")
    srv = ServeProcess(secret=SECRET, workers="auto")
    try:
        srv.wait_ready()
        pinned = {i: os.sched_getaffinity(pid) for i, pid in worker_pids(srv).items()}
        assert pinned == {i: {cpu} for i, cpu in enumerate(cpus)}
        assert srv.metrics()['posecast_workers{worker="supervisor"}'] == len(cpus)
    finally:
        srv.stop()
