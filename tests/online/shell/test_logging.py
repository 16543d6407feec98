"""JSON logs (online.shell.logging): one object per line with the record's extras, an
exception in the same line, and configure setting up the posecast and websockets loggers."""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Iterator
from pathlib import Path

import pytest

from posecast.online.shell.logging import JsonFormatter, configure


@pytest.fixture
def restore_logging() -> Iterator[None]:
    saved = {}
    for name in ("posecast", "websockets"):
        lg = logging.getLogger(name)
        saved[name] = (lg.handlers[:], lg.level, lg.propagate)
    yield
    for name, (handlers, level, propagate) in saved.items():
        lg = logging.getLogger(name)
        lg.handlers[:], lg.propagate = handlers, propagate
        lg.setLevel(level)


def test_json_lines_carry_the_extras(restore_logging: None) -> None:
    stream = io.StringIO()
    configure("INFO", stream)
    logging.getLogger("posecast.test").info("join", extra={"player": "p1", "room": "r"})
    logging.getLogger("posecast.test").debug("hidden")
    (line,) = stream.getvalue().splitlines()
    rec = json.loads(line)
    assert rec["event"] == "join" and rec["player"] == "p1" and rec["level"] == "INFO"


def test_exceptions_are_one_json_line() -> None:
    try:
        raise ValueError("boom")
    except ValueError:
        import sys

        rec = logging.LogRecord("x", logging.ERROR, "f", 1, "failed", None, sys.exc_info())
    out = json.loads(JsonFormatter().format(rec))
    assert out["event"] == "failed" and "ValueError: boom" in out["exc"]


def test_configure_sends_posecast_at_its_level_and_websockets_at_warning(
    restore_logging: None,
) -> None:
    stream = io.StringIO()
    configure("debug", stream)
    logging.getLogger("posecast.x").debug("seen", extra={"n": 1})
    logging.getLogger("websockets.server").info("not seen")
    logging.getLogger("websockets.server").warning("seen too")
    rows = [json.loads(line) for line in stream.getvalue().splitlines()]
    assert [(r["logger"], r["event"], r["level"]) for r in rows] == [
        ("posecast.x", "seen", "DEBUG"),
        ("websockets.server", "seen too", "WARNING"),
    ]
    assert rows[0]["n"] == 1 and isinstance(rows[0]["ts"], float)
    assert not logging.getLogger("posecast").propagate  # not twice through the root logger
    configure("INFO", stream)  # again: still one handler, not two
    assert len(logging.getLogger("posecast").handlers) == 1


def test_values_json_cannot_hold_are_written_as_text() -> None:
    rec = logging.LogRecord("posecast.x", logging.INFO, "f", 1, "odd", None, None)
    rec.path = Path("/tmp/a")
    rec._private = 1
    out = json.loads(JsonFormatter().format(rec))
    assert out["path"] == "/tmp/a" and "_private" not in out
    assert set(out) == {"ts", "level", "logger", "event", "path"}
