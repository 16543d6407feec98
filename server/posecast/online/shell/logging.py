"""Structured logs: stdlib :mod:`logging` with one JSON object per line.

Call sites log an event name as the message and the details as ``extra``::

    log.info("join", extra={"player": "p1", "room": "lobby"})

and :class:`JsonFormatter` writes ``{"ts": ..., "level": "INFO", "logger": ...,
"event": "join", "player": "p1", "room": "lobby"}``. :func:`configure` is called once,
by the CLI, at the edge.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import IO, Any

# Attributes every LogRecord has; anything else on a record came from ``extra``.
_STANDARD = set(vars(logging.LogRecord("", 0, "", 0, "", None, None))) | {"message", "asctime"}


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "ts": round(record.created, 6),
            "level": record.levelname,
            "logger": record.name,
            "event": record.getMessage(),
        }
        for key, value in vars(record).items():
            if key not in _STANDARD and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str, separators=(",", ":"))

    def formatTime(self, record: logging.LogRecord, datefmt: str | None = None) -> str:
        return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))


def configure(level: str = "INFO", stream: IO[str] | None = None) -> None:
    """JSON lines on ``stream`` (stderr) for the ``posecast`` and ``websockets`` loggers."""
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(JsonFormatter())
    for name in ("posecast", "websockets"):
        logger = logging.getLogger(name)
        logger.handlers[:] = [handler]
        logger.setLevel(level.upper() if name == "posecast" else "WARNING")
        logger.propagate = False
