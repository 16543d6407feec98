"""Reading Acclaim text: the lines of a file (plain or gzip, any line ends) and its
numbers, every problem an :class:`~posecast.errors.AcclaimError` naming the file and
the line. Shared by :mod:`~posecast.offline.motion.acclaim_asf` and
:mod:`~posecast.offline.motion.acclaim_amc`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from posecast.errors import AcclaimError
from posecast.offline.motion.gzfile import read_maybe_gzip


def read_lines(path: str | Path) -> list[str]:
    """The lines of a text file, plain or gzip, any line ends (AcclaimError if unreadable)."""
    p = Path(path)
    raw = read_maybe_gzip(p, AcclaimError)
    if b"\x00" in raw:
        raise AcclaimError(
            "not a text file", file=p, line=raw[: raw.index(b"\x00")].count(b"\n") + 1
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # HDM05 comments carry Latin-1 path names
    # LF, CRLF or CR; not str.splitlines, which also breaks at Latin-1's NEL (0x85) and
    # would put every later line number off.
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if lines and not lines[-1]:
        lines.pop()
    return lines


def floats(tokens: Sequence[str], n: int, what: str, source: str, line: int) -> list[float]:
    """``n`` finite numbers from ``tokens``, the ``what`` of line ``line`` of ``source``."""
    if len(tokens) != n:
        raise AcclaimError(
            f"{what}: expected {n} number(s), found {len(tokens)}", file=source, line=line
        )
    try:
        out = [float(t) for t in tokens]
    except ValueError:
        bad = next(t for t in tokens if not is_float(t))
        raise AcclaimError(f"{what}: {bad!r} is not a number", file=source, line=line) from None
    if not all(math.isfinite(v) for v in out):
        raise AcclaimError(f"{what}: non-finite value", file=source, line=line)
    return out


def is_float(t: str) -> bool:
    """``t`` reads as a float."""
    try:
        float(t)
    except ValueError:
        return False
    return True
