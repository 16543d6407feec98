"""A motion file's bytes, plain or gzip by content (offline.motion.gzfile), and the error
class each reader asks for when they cannot be read."""

from __future__ import annotations

import gzip
from pathlib import Path

import pytest

from posecast.errors import AcclaimError, BvhError
from posecast.offline.motion.gzfile import read_maybe_gzip

DATA = b"HIERARCHY\nROOT Hips\n"


def test_plain_and_gzip_read_the_same_whatever_the_name(tmp_path: Path) -> None:
    plain = tmp_path / "take.bvh.gz"  # the name says gzip; the content does not
    plain.write_bytes(DATA)
    packed = tmp_path / "take.bvh"  # and the other way round
    packed.write_bytes(gzip.compress(DATA))
    assert read_maybe_gzip(plain, BvhError) == DATA
    assert read_maybe_gzip(packed, BvhError) == DATA


@pytest.mark.parametrize("error", [BvhError, AcclaimError])
def test_unreadable_and_corrupt_files_raise_the_callers_error(
    tmp_path: Path, error: type[BvhError] | type[AcclaimError]
) -> None:
    absent = tmp_path / "absent.bvh"
    with pytest.raises(error, match="cannot read file") as info:
        read_maybe_gzip(absent, error)
    assert info.value.file == str(absent)
    truncated = tmp_path / "cut.bvh.gz"
    truncated.write_bytes(gzip.compress(DATA)[:12])
    with pytest.raises(error, match="corrupt gzip stream") as info:
        read_maybe_gzip(truncated, error)
    assert info.value.file == str(truncated) and info.value.line is None
