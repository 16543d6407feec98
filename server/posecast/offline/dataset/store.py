"""Reading a prepared dataset back."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from posecast.errors import DatasetError
from posecast.offline.dataset.frames import FIELDS, Frames
from posecast.offline.dataset.prepare import DATASET_FORMAT, DATASET_VERSION


@dataclass(frozen=True)
class SplitData:
    """One split: concatenated per-frame arrays and where each clip starts."""

    name: str
    frames: Frames
    clip_start: NDArray[np.int64]
    clips: list[dict[str, object]]
    fps: float

    @property
    def n_clips(self) -> int:
        return len(self.clip_start) - 1

    def clip(self, i: int) -> Frames:
        a, b = int(self.clip_start[i]), int(self.clip_start[i + 1])
        return {k: v[a:b] for k, v in self.frames.items()}


def read_manifest(root: str | Path) -> dict[str, object]:
    path = Path(root) / "manifest.json"
    try:
        manifest = json.loads(path.read_text("utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetError(f"cannot read manifest: {exc}", path=root) from exc
    if manifest.get("format") != DATASET_FORMAT or manifest.get("version") != DATASET_VERSION:
        raise DatasetError(
            f"not a {DATASET_FORMAT} v{DATASET_VERSION} directory; run `posecast data prepare`",
            path=root,
        )
    return dict(manifest)


def load_split(root: str | Path, split: str) -> SplitData:
    manifest = read_manifest(root)
    path = Path(root) / f"{split}.npz"
    try:
        with np.load(path) as z:
            frames = {k: z[k] for k in FIELDS}
            starts = z["clip_start"]
    except (OSError, KeyError, ValueError) as exc:
        raise DatasetError(f"cannot read {path.name}: {exc}", path=root) from exc
    clips = manifest["clips"][split]  # type: ignore[index]
    return SplitData(split, frames, starts, list(clips), float(manifest["fps"]))  # type: ignore[arg-type]
