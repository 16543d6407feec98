"""The supervisor's pieces that need no worker process (posecast.online.shell.workers):
the port held for the workers, and what a worker reads on its stdin. The supervisor
with real workers runs in ``tests/system/test_workers.py``."""

from __future__ import annotations

import errno
import json
import socket

import pytest

from posecast.online.config import ServerConfig
from posecast.online.shell.workers import reserve_port, worker_cpus, worker_spec
from tests.online.conftest import SECRET, make_cfg


def _listener(port: int) -> socket.socket:
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    s.bind(("127.0.0.1", port))
    s.listen()
    return s


def test_a_reserved_port_takes_no_connection_and_the_workers_listeners_share_it() -> None:
    held, port = reserve_port("127.0.0.1", 0)
    listeners = [_listener(port), _listener(port)]
    try:
        assert port > 0 and [s.getsockname()[1] for s in held] == [port]
        counts = [0, 0]
        for s in listeners:
            s.settimeout(2.0)
        for _ in range(40):
            with socket.create_connection(("127.0.0.1", port), timeout=2.0):
                for i, s in enumerate(listeners):
                    s.setblocking(False)
                    try:
                        conn, _ = s.accept()
                        conn.close()
                        counts[i] += 1
                    except BlockingIOError:
                        pass
        assert sum(counts) == 40  # every one reached a listener, none the held socket
        assert min(counts) > 0  # the kernel spreads them over both
    finally:
        for s in held + listeners:
            s.close()


def test_a_port_in_use_is_refused_as_a_bind_would_be() -> None:
    plain = socket.socket()
    plain.bind(("127.0.0.1", 0))
    plain.listen()
    try:
        with pytest.raises(OSError) as caught:
            reserve_port("127.0.0.1", plain.getsockname()[1])
        assert caught.value.errno == errno.EADDRINUSE
    finally:
        plain.close()


def test_every_interface_gets_one_port_on_both_families() -> None:
    if not socket.has_ipv6:
        pytest.skip("no IPv6 on this host")
    held, port = reserve_port("", 0)
    try:
        families = {s.family for s in held}
        assert families == {socket.AF_INET, socket.AF_INET6}
        assert {s.getsockname()[1] for s in held} == {port}
    finally:
        for s in held:
            s.close()


def test_a_worker_rebuilds_the_very_config_it_was_handed() -> None:
    cfg = make_cfg(workers="2", samples=12, no_upper_ik=True, layouts="hmd3", dev=True)
    spec = json.loads(worker_spec(cfg, 1, "/tmp/x/relay.sock", cpu=3))
    assert spec["index"] == 1 and spec["relay"] == "/tmp/x/relay.sock" and spec["cpu"] == 3
    assert ServerConfig(**spec["config"]) == cfg
    assert spec["config"]["token_secret"] == SECRET  # on stdin: never on a command line


def test_auto_gives_each_worker_a_cpu_of_its_own_and_a_number_pins_none() -> None:
    import os

    assert worker_cpus(make_cfg(workers="auto")) == sorted(os.sched_getaffinity(0))
    assert worker_cpus(make_cfg(workers="2")) == []
