"""A small generated BVH tree, prepared once per session, for the dataset tests.

Subjects are picked so that every split gets clips from the committed table
(1 -> train, 6 and 13 -> val, 5 -> test) and two are unknown to it and placed by
hash ("alice" -> val, "11" -> test). Both CMU layouts, plain and gzip files, and
one subject (1) recorded on both rigs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from posecast.offline.dataset.prepare import PrepareReport, prepare
from posecast.offline.motion.rig import load_rigs
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh

SOURCE_FPS = 120.0


@dataclass(frozen=True)
class Fixture:
    """One generated file: where, which layout, which procedural walk."""

    rel: str
    layout: str
    seconds: float
    seed: int
    subject: str

    @property
    def name(self) -> str:
        return Path(self.rel).name.split(".")[0]

    @property
    def frames_60(self) -> int:
        """Frames after preparation: 120 -> 60 fps (the CMU layouts' T-pose is extra)."""
        n_src = round(self.seconds * SOURCE_FPS)
        return (n_src - 1) // 2 + 1


GOOD_FILES: tuple[Fixture, ...] = (
    Fixture("mb/01/01_01.bvh.gz", "cmu_mb", 1.5, 11, "1"),
    Fixture("mb/01/01_02.bvh", "cmu_mb", 1.0, 12, "1"),
    Fixture("daz/01/01_03.bvh.gz", "cmu_daz", 1.25, 13, "1"),
    Fixture("mb/06/06_01.bvh.gz", "cmu_mb", 1.0, 61, "6"),
    Fixture("daz/13/13_02.bvh", "cmu_daz", 1.5, 132, "13"),
    Fixture("mb/05/05_02.bvh", "cmu_mb", 1.25, 52, "5"),
    Fixture("daz/05/05_03.bvh.gz", "cmu_daz", 1.0, 53, "5"),
    Fixture("mb/11/11_01.bvh.gz", "cmu_mb", 1.0, 111, "11"),
    Fixture("captures/alice/take1.bvh", "posecast", 1.0, 7, "alice"),
)


def write_fixture(root: Path, fx: Fixture) -> Path:
    path = root / fx.rel
    path.parent.mkdir(parents=True, exist_ok=True)
    clip = walk_clip(seconds=fx.seconds, fps=SOURCE_FPS, seed=fx.seed, name=fx.name)
    write_fixture_bvh(path, clip, fx.layout)
    return path


@pytest.fixture(scope="session")
def good_files() -> tuple[Fixture, ...]:
    return GOOD_FILES


@pytest.fixture(scope="session")
def bvh_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("bvh")
    for fx in GOOD_FILES:
        write_fixture(root, fx)
    return root


@pytest.fixture(scope="session")
def prepared(
    bvh_tree: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, PrepareReport]:
    out = tmp_path_factory.mktemp("prepared")
    report = prepare(bvh_tree, out, load_rigs())
    return out, report
