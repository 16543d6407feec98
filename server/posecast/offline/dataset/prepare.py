"""``posecast data prepare``: a BVH tree in, a cached canonical dataset out.

The output directory holds ``manifest.json`` (what went in, what was skipped, the
split statistics) and one ``<split>.npz`` per split with the arrays of
:mod:`posecast.offline.dataset.frames` for every clip, concatenated, plus ``clip_start``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from posecast import __version__
from posecast.errors import DataError
from posecast.offline.dataset.frames import Frames, concat_frames, derive_frames
from posecast.offline.dataset.split import SPLITS, load_split_table, split_of, subject_of
from posecast.offline.motion.bvh import read_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.retarget import TARGET_FPS, retarget
from posecast.offline.motion.rig import Rig, detect_rig

DATASET_FORMAT = "posecast-dataset"
DATASET_VERSION = 1


@dataclass
class SplitStats:
    sequences: int = 0
    frames: int = 0
    contact_frames: int = 0  # foot-frames in contact (two per frame)
    subjects: set[str] = field(default_factory=set)

    def as_dict(self, fps: float) -> dict[str, object]:
        return {
            "hours": round(self.frames / fps / 3600.0, 4),
            "sequences": self.sequences,
            "frames": self.frames,
            "contact_ratio": round(self.contact_frames / max(1, 2 * self.frames), 4),
            "subjects": sorted(self.subjects, key=lambda s: (len(s), s)),
        }


@dataclass
class PrepareReport:
    out_dir: Path
    stats: dict[str, SplitStats]
    skipped: list[tuple[str, str]]
    seconds: float
    fps: float = TARGET_FPS

    def table(self) -> str:
        lines = [f"{'split':6s} {'hours':>7s} {'seqs':>5s} {'frames':>8s} {'contact':>8s}"]
        for name in SPLITS:
            d = self.stats[name].as_dict(self.fps)
            lines.append(
                f"{name:6s} {d['hours']:7.3f} {d['sequences']:5d} {d['frames']:8d} "
                f"{d['contact_ratio']:8.3f}"
            )
        if self.skipped:
            lines.append(f"skipped {len(self.skipped)} file(s):")
            lines += [f"  {f}: {why}" for f, why in self.skipped]
        return "\n".join(lines)


def find_bvh_files(root: str | Path) -> list[Path]:
    """Every ``*.bvh`` and ``*.bvh.gz`` below ``root``, sorted."""
    r = Path(root)
    if r.is_file():
        return [r]
    if not r.is_dir():
        raise DataError(f"{r}: no such directory")
    return sorted(p for p in r.rglob("*") if p.is_file() and p.name.endswith((".bvh", ".bvh.gz")))


def process_file(
    path: Path, rigs: list[Rig], rig_name: str | None = None
) -> tuple[CanonicalClip, Frames, Rig]:
    """Read, match, retarget and derive one BVH file (raises DataError subclasses)."""
    bvh = read_bvh(path)
    rig = detect_rig(bvh, rigs, rig_name)
    clip = retarget(bvh, rig, name=path.name.split(".")[0], subject=subject_of(path))
    return clip, derive_frames(clip), rig


def prepare(
    bvh_root: str | Path,
    out_dir: str | Path,
    rigs: list[Rig],
    *,
    rig_name: str | None = None,
    skip_bad: bool = False,
    split_file: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> PrepareReport:
    """Read, retarget and derive every BVH below ``bvh_root``; write the dataset.

    Raises the first :class:`~posecast.errors.DataError` unless ``skip_bad``, in
    which case bad files are listed in the report and the manifest.
    """
    t0 = time.perf_counter()
    files = find_bvh_files(bvh_root)
    if not files:
        raise DataError(f"{bvh_root}: no .bvh or .bvh.gz files found")
    table = load_split_table(split_file)
    parts: dict[str, list[Frames]] = {s: [] for s in SPLITS}
    clips: dict[str, list[dict[str, object]]] = {s: [] for s in SPLITS}
    stats = {s: SplitStats() for s in SPLITS}
    skipped: list[tuple[str, str]] = []
    for path in files:
        try:
            clip, frames, rig = process_file(path, rigs, rig_name)
        except DataError as exc:
            if not skip_bad:
                raise
            skipped.append((str(path), str(exc)))
            if progress:
                progress(f"skip {path}: {exc}")
            continue
        subject = clip.subject
        split = split_of(subject, table)
        parts[split].append(frames)
        n = clip.n_frames
        clips[split].append(
            {
                "name": clip.name,
                "subject": subject,
                "rig": rig.name,
                "source": str(path),
                "frames": n,
            }
        )
        st = stats[split]
        st.sequences += 1
        st.frames += n
        st.contact_frames += int(frames["contacts"].sum())
        st.subjects.add(subject)
        if progress:
            progress(f"{split:5s} {path.name} ({rig.name}, {n} frames)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for split in SPLITS:
        arrays, starts = concat_frames(parts[split])
        np.savez(out / f"{split}.npz", clip_start=starts, **arrays)  # type: ignore[arg-type]
    manifest = {
        "format": DATASET_FORMAT,
        "version": DATASET_VERSION,
        "posecast_version": __version__,
        "fps": TARGET_FPS,
        "source_root": str(bvh_root),
        "splits": {s: stats[s].as_dict(TARGET_FPS) for s in SPLITS},
        "clips": clips,
        "skipped": [{"file": f, "error": e} for f, e in skipped],
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    return PrepareReport(out, stats, skipped, time.perf_counter() - t0)
