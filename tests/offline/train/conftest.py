"""A small prepared dataset, generated from procedural motion (no ../shared needed)."""

from __future__ import annotations

from pathlib import Path

import pytest

from posecast.offline.dataset.prepare import prepare
from posecast.offline.motion.rig import load_rigs
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh

# CMU subject numbers chosen so the committed split sends them to train, val and test.
_SUBJECTS = {"01": "cmu_mb", "09": "cmu_mb", "06": "cmu_mb", "05": "cmu_daz"}


@pytest.fixture(scope="session")
def prepared_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fixture_data")
    bvh = root / "bvh"
    for i, (subject, layout) in enumerate(_SUBJECTS.items()):
        folder = bvh / subject
        folder.mkdir(parents=True)
        clip = walk_clip(seconds=5.0, fps=120.0, seed=i)
        write_fixture_bvh(folder / f"{subject}_01.bvh", clip, layout)
    out = root / "prepared"
    prepare(bvh, out, load_rigs())
    return out
