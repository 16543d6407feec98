"""The bytes of a motion file, plain or gzip-compressed (detected by content, not by
name): what :func:`~posecast.offline.motion.bvh.read_bvh` and the Acclaim readers
(:mod:`~posecast.offline.motion.acclaim_text`) both start from."""

from __future__ import annotations

import gzip
import zlib
from pathlib import Path

from posecast.errors import AcclaimError, BvhError


def read_maybe_gzip(path: Path, error: type[BvhError] | type[AcclaimError]) -> bytes:
    """The bytes of ``path``, decompressed when they start with the gzip magic; ``error``
    (naming the file) when it cannot be read or its gzip stream is corrupt."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read file: {exc.strerror or exc}", file=path) from exc
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as exc:  # BadGzipFile is an OSError
            raise error(f"corrupt gzip stream: {exc}", file=path) from exc
    return raw
