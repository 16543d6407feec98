"""What the tests of the ``posecast`` command line share (called in-process through
``posecast.cli.main``).

Every error a user can cause ends as ``posecast: error [CODE]: message`` and a
``hint:`` line on stderr, exit status 2, and no traceback: one test at least per
subcommand provokes one (``test_*_user_error`` and the tests around them), and
:func:`user_error` checks it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh


def user_error(capsys: pytest.CaptureFixture[str], rc: int, code: str) -> str:
    """Assert a clean user error with ``code``; returns stderr."""
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err, err
    lines = err.splitlines()
    at = [i for i, ln in enumerate(lines) if ln.startswith(f"posecast: error [{code}]: ")]
    assert at, err
    assert lines[at[0] + 1].startswith("hint: ") and len(lines[at[0] + 1]) > 10, err
    return err


def write_bvh(root: Path, rel: str, layout: str, seed: int) -> Path:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    write_fixture_bvh(path, walk_clip(seconds=0.5, fps=120.0, seed=seed), layout)
    return path


@pytest.fixture
def bvh_dir(tmp_path: Path) -> Path:
    root = tmp_path / "bvh"
    write_bvh(root, "mb/01/01_01.bvh.gz", "cmu_mb", 1)  # train
    write_bvh(root, "daz/13/13_01.bvh", "cmu_daz", 2)  # val
    write_bvh(root, "mb/05/05_01.bvh", "cmu_mb", 3)  # test
    return root
