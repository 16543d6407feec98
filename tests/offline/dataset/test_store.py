"""Reading a prepared dataset back (offline.dataset.store): the splits' arrays, their clip
boundaries and the errors for what is not a dataset."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from posecast.errors import DatasetError
from posecast.offline.dataset.frames import FIELDS
from posecast.offline.dataset.prepare import DATASET_VERSION
from posecast.offline.dataset.split import SPLITS
from posecast.offline.dataset.store import load_split, read_manifest
from posecast.offline.motion.synthetic import walk_clip

from .conftest import SOURCE_FPS


def test_npz_arrays_and_clip_boundaries(prepared, good_files) -> None:
    out, _ = prepared
    by_name = {fx.name: fx for fx in good_files}
    with np.load(out / "train.npz") as z:
        assert set(z.files) == {*FIELDS, "clip_start"}
    for split in SPLITS:
        data = load_split(out, split)
        assert data.fps == 60.0
        assert data.n_clips == len(data.clips)
        assert data.clip_start[0] == 0
        np.testing.assert_array_equal(np.diff(data.clip_start), [c["frames"] for c in data.clips])
        total = int(data.clip_start[-1])
        for name, shape in FIELDS.items():
            assert data.frames[name].shape == (total, *shape), name
            assert data.frames[name].dtype == np.float32
        for i, entry in enumerate(data.clips):
            # Each slice is its own clip: the prepared motion is the generated walk,
            # T-pose dropped and taken every other frame (120 -> 60 fps).
            fx = by_name[str(entry["name"])]
            walk = walk_clip(seconds=fx.seconds, fps=SOURCE_FPS, seed=fx.seed)
            _, want = walk.fk()
            got = data.clip(i)["positions"]
            assert got.shape == want[::2].shape
            np.testing.assert_allclose(got, want[::2], atol=2e-3, err_msg=fx.name)


def test_reading_back_something_that_is_not_a_dataset(tmp_path: Path, prepared) -> None:
    with pytest.raises(DatasetError):
        read_manifest(tmp_path)
    copy = tmp_path / "copy"
    shutil.copytree(prepared[0], copy)
    manifest = json.loads((copy / "manifest.json").read_text("utf-8"))
    manifest["version"] = DATASET_VERSION + 1
    (copy / "manifest.json").write_text(json.dumps(manifest), "utf-8")
    with pytest.raises(DatasetError, match="posecast data prepare"):
        load_split(copy, "train")
    manifest["version"] = DATASET_VERSION
    (copy / "manifest.json").write_text(json.dumps(manifest), "utf-8")
    (copy / "val.npz").unlink()
    with pytest.raises(DatasetError, match=r"val\.npz"):
        load_split(copy, "val")
