"""The ``posecast serve`` subprocess helper (posecast.testing.serve): reading the
exposition format by series and summing it by labels, the process figures from
``/proc``, a plain GET, and one real server started, read and stopped."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from posecast.testing.serve import (
    ServeProcess,
    cpu_seconds,
    http_get,
    metric_sum,
    parse_metrics,
    parse_series,
    rss_bytes,
    series_name,
)

SECRET = "s" * 32
TEXT = """\
# HELP posecast_errors_total Errors sent, by code
# TYPE posecast_errors_total counter
posecast_errors_total{code="TOO_LARGE",fatal="true"} 3.0
posecast_errors_total{code="BAD_FIELD",fatal="false"} 4.0
posecast_errors_total{code="BAD_FIELD",fatal="true"} 1.0
# HELP posecast_players Players joined
# TYPE posecast_players gauge
posecast_players 7.0
# HELP posecast_odd Odd label values
# TYPE posecast_odd gauge
posecast_odd{room="a\\"b\\\\c"} 2.0
"""


def test_series_are_keyed_by_name_and_sorted_labels() -> None:
    assert series_name("x", {}) == "x"
    assert series_name("x", {"b": "2", "a": "1"}) == 'x{a="1",b="2"}'
    assert series_name("x", {"r": 'a"b\\c\nd'}) == 'x{r="a\\"b\\\\c\\nd"}'
    series = parse_series(TEXT)
    assert series[("posecast_players", ())] == 7.0
    assert series[("posecast_odd", (("room", 'a"b\\c'),))] == 2.0
    metrics = parse_metrics(TEXT)
    assert metrics['posecast_errors_total{code="BAD_FIELD",fatal="false"}'] == 4.0
    assert metrics["posecast_players"] == 7.0


def test_sums_match_labels_given_as_arguments_or_inline() -> None:
    m = parse_metrics(TEXT)
    assert metric_sum(m, "posecast_errors_total") == 8.0
    assert metric_sum(m, "posecast_errors_total", code="BAD_FIELD") == 5.0
    assert metric_sum(m, 'posecast_errors_total{code="BAD_FIELD"}', fatal="true") == 1.0
    assert metric_sum(m, "posecast_errors_total", code="NOPE") == 0.0
    assert metric_sum(m, "posecast_odd", room='a"b\\c') == 2.0
    assert metric_sum(m, "posecast_err") == 0.0  # a prefix is not a name


def test_process_figures_come_from_proc() -> None:
    assert rss_bytes(os.getpid()) > 10 * 2**20  # this interpreter, numpy loaded
    spent = cpu_seconds(os.getpid())
    sum(i * i for i in range(200_000))
    assert cpu_seconds(os.getpid()) >= spent > 0


@pytest.fixture
def http_port() -> Iterator[int]:
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            status = 200 if self.path == "/ok" else 503
            body = f"{self.path} {status}".encode()
            self.send_response(status)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def test_a_get_returns_error_statuses_with_their_body(http_port: int) -> None:
    assert http_get(http_port, "/ok") == (200, "/ok 200")
    assert http_get(http_port, "/readyz") == (503, "/readyz 503")


@pytest.mark.timeout(120)
def test_a_real_server_starts_answers_and_stops_gracefully() -> None:
    with ServeProcess(secret=SECRET, samples=2, lookahead=1) as server:
        assert server.cmd[-4:] == ["--samples", "2", "--lookahead", "1"]
        assert server.port > 0 and server.url == f"ws://127.0.0.1:{server.port}/"
        server.wait_ready()
        assert server.alive() and server.http("/healthz")[0] == 200
        assert server.metric("posecast_players") == 0.0
        assert "posecast_rooms" in server.metrics()
        assert server.rss_bytes() > 0 and server.fds() > 0
    assert server.proc.poll() == 0  # SIGTERM: a graceful stop, exit status 0
    assert not server.alive()


def test_a_server_that_cannot_start_says_so() -> None:
    with pytest.raises(RuntimeError, match="did not start"):
        ServeProcess("--tick-hz", "0", secret=SECRET)
