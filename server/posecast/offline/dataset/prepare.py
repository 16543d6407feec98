"""``posecast data prepare``: BVH and ASF/AMC trees in, a cached canonical dataset out.

Sources, in any mix: BVH trees (``*.bvh``, ``*.bvh.gz``), ASF/AMC trees (``*.amc``,
``*.amc.gz``, each read with the ``.asf``/``.asx`` skeleton of its subject in the same
folder, see :func:`find_asf_for`) and HDM05 trees (ASF/AMC as well, but opt-in on
their own: HDM05 is CC BY-SA 3.0, so the manifest records its use, licence and
citation for the model card). Every file goes through the same rig detection,
retargeting and derivation.

The output directory holds ``manifest.json`` (what went in, what was skipped, the
split statistics) and one ``<split>.npz`` per split with the arrays of
:mod:`posecast.offline.dataset.frames` for every clip, concatenated, plus ``clip_start``.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from posecast import __version__
from posecast.errors import AcclaimError, DataError
from posecast.offline.dataset.frames import Frames, concat_frames, derive_frames
from posecast.offline.dataset.split import SPLITS, load_split_table, split_of, subject_of
from posecast.offline.motion.acclaim import DEFAULT_FPS, read_acclaim
from posecast.offline.motion.bvh import Bvh, read_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.retarget import TARGET_FPS, retarget
from posecast.offline.motion.rig import Rig, detect_rig

DATASET_FORMAT = "posecast-dataset"
DATASET_VERSION = 1

BVH_SUFFIXES = (".bvh", ".bvh.gz")
AMC_SUFFIXES = (".amc", ".amc.gz")
ASF_SUFFIXES = (".asf", ".asf.gz", ".asx", ".asx.gz")

# The kinds of source tree. "hdm05" is ASF/AMC too, but opt-in and recorded apart.
SOURCE_KINDS = ("bvh", "amc", "hdm05")
HDM05_LICENCE = "CC BY-SA 3.0 (Creative Commons Attribution-ShareAlike 3.0 Unported)"
HDM05_CITATION = (
    "M. Mueller, T. Roeder, M. Clausen, B. Eberhardt, B. Krueger, A. Weber: "
    "Documentation Mocap Database HDM05. Technical report CG-2007-2, "
    "Universitaet Bonn, 2007."
)
_HDM05_NAME = re.compile(r"^HDM_[A-Za-z]+_")
_HDM05_FPS = re.compile(r"^HDM_.*_(\d+)$")


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
    sources: list[dict[str, object]] = field(default_factory=list)

    def table(self) -> str:
        lines = [f"{'split':6s} {'hours':>7s} {'seqs':>5s} {'frames':>8s} {'contact':>8s}"]
        for name in SPLITS:
            d = self.stats[name].as_dict(self.fps)
            lines.append(
                f"{name:6s} {d['hours']:7.3f} {d['sequences']:5d} {d['frames']:8d} "
                f"{d['contact_ratio']:8.3f}"
            )
        if self.sources and any(src["kind"] != "bvh" for src in self.sources):
            lines.append(
                "sources: "
                + ", ".join(
                    f"{src['kind']} {src['root']} ({src['files']} files)" for src in self.sources
                )
            )
        if self.skipped:
            lines.append(f"skipped {len(self.skipped)} file(s):")
            lines += [f"  {f}: {why}" for f, why in self.skipped]
        return "\n".join(lines)


def _find(root: str | Path, suffixes: tuple[str, ...]) -> list[Path]:
    r = Path(root)
    if r.is_file():
        return [r]
    if not r.is_dir():
        raise DataError(f"{r}: no such directory")
    return sorted(p for p in r.rglob("*") if p.is_file() and p.name.endswith(suffixes))


def find_bvh_files(root: str | Path) -> list[Path]:
    """Every ``*.bvh`` and ``*.bvh.gz`` below ``root``, sorted."""
    return _find(root, BVH_SUFFIXES)


def find_amc_files(root: str | Path) -> list[Path]:
    """Every ``*.amc`` and ``*.amc.gz`` below ``root``, sorted."""
    return _find(root, AMC_SUFFIXES)


def is_amc(path: str | Path) -> bool:
    return Path(path).name.endswith(AMC_SUFFIXES)


def is_hdm05(path: str | Path) -> bool:
    """Whether a file is named like an HDM05 take (``HDM_<actor>_...``)."""
    return bool(_HDM05_NAME.match(Path(path).name))


def _stem(name: str, suffixes: tuple[str, ...]) -> str:
    for suf in sorted(suffixes, key=len, reverse=True):
        if name.endswith(suf):
            return name[: -len(suf)]
    return name


def find_asf_for(amc: str | Path) -> Path:
    """The skeleton of an AMC take: the ``.asf``/``.asx`` (plain or ``.gz``) beside it.

    With several, the one whose name starts the AMC's name (``135.asf`` for
    ``135_02.amc``, ``HDM_bd.asf`` for ``HDM_bd_squat1Reps_001_120.amc``), the longest
    such if more than one does; a lone skeleton file in the folder serves any AMC.
    """
    p = Path(amc)
    stem = _stem(p.name, AMC_SUFFIXES)
    candidates = sorted(
        q for q in p.parent.iterdir() if q.is_file() and q.name.endswith(ASF_SUFFIXES)
    )
    named = [
        q
        for q in candidates
        if stem == _stem(q.name, ASF_SUFFIXES) or stem.startswith(_stem(q.name, ASF_SUFFIXES) + "_")
    ]
    if named:
        return max(named, key=lambda q: (len(_stem(q.name, ASF_SUFFIXES)), q.name))
    if len(candidates) == 1:
        return candidates[0]
    subject = stem.split("_")[0] or stem
    if not candidates:
        why = f"no skeleton: expected {subject}.asf (or .asx, plain or .gz) in the same folder"
    else:
        names = ", ".join(q.name for q in candidates)
        why = f"no skeleton named for it among {names} (expected {subject}.asf)"
    raise AcclaimError(why, file=p)


def amc_frame_rate(path: str | Path, default: float = DEFAULT_FPS) -> float:
    """AMC files store no frame rate: HDM05 names end in it (``..._120``), else ``default``."""
    m = _HDM05_FPS.match(_stem(Path(path).name, AMC_SUFFIXES))
    if m and int(m.group(1)) > 0:
        return float(m.group(1))
    return default


def read_motion(path: str | Path, *, amc_fps: float = DEFAULT_FPS) -> Bvh:
    """A BVH file, or an AMC take with its skeleton (:func:`find_asf_for`), as :class:`Bvh`."""
    p = Path(path)
    if not is_amc(p):
        return read_bvh(p)
    bvh = read_acclaim(find_asf_for(p), p, amc_frame_rate(p, amc_fps))
    if bvh.n_frames < 2:
        raise AcclaimError("fewer than 2 frames of motion", file=p)
    return bvh


def process_file(
    path: Path, rigs: list[Rig], rig_name: str | None = None, *, amc_fps: float = DEFAULT_FPS
) -> tuple[CanonicalClip, Frames, Rig]:
    """Read, match, retarget and derive one BVH or AMC file (raises DataError subclasses)."""
    bvh = read_motion(path, amc_fps=amc_fps)
    rig = detect_rig(bvh, rigs, rig_name)
    clip = retarget(bvh, rig, name=path.name.split(".")[0], subject=subject_of(path))
    return clip, derive_frames(clip), rig


Roots = str | Path | Sequence[str | Path] | None


def _roots(value: Roots) -> list[Path]:
    if value is None:
        return []
    if isinstance(value, str | Path):
        return [Path(value)]
    return [Path(v) for v in value]


def _gather(
    bvh_roots: list[Path], amc_roots: list[Path], hdm05_roots: list[Path]
) -> tuple[list[tuple[Path, int]], list[dict[str, object]]]:
    """Every input file with the index of its source, and the sources for the manifest."""
    files: list[tuple[Path, int]] = []
    sources: list[dict[str, object]] = []
    seen: set[Path] = set()
    for kind, roots in (("bvh", bvh_roots), ("amc", amc_roots), ("hdm05", hdm05_roots)):
        for root in roots:
            found = find_bvh_files(root) if kind == "bvh" else find_amc_files(root)
            if not found:
                what = ".bvh or .bvh.gz" if kind == "bvh" else ".amc or .amc.gz"
                raise DataError(f"{root}: no {what} files found")
            if kind == "amc":
                hdm = [p for p in found if is_hdm05(p)]
                if hdm:
                    exc = DataError(
                        f"{root}: holds HDM05 takes ({hdm[0].name}, ...); HDM05 is "
                        "CC BY-SA 3.0 and opt-in, so it is read only as an HDM05 source"
                    )
                    exc.add_note("hint: pass that folder with --hdm05 DIR instead of --amc")
                    raise exc
            new = [p for p in found if p.resolve() not in seen]
            seen.update(p.resolve() for p in new)
            files += [(p, len(sources)) for p in new]
            entry: dict[str, object] = {"kind": kind, "root": str(root), "files": len(new)}
            if kind == "hdm05":
                entry["licence"] = HDM05_LICENCE
                entry["citation"] = HDM05_CITATION
            sources.append(entry)
    return files, sources


def prepare(
    bvh_root: Roots,
    out_dir: str | Path,
    rigs: list[Rig],
    *,
    amc_roots: Roots = None,
    hdm05_roots: Roots = None,
    amc_fps: float = DEFAULT_FPS,
    rig_name: str | None = None,
    skip_bad: bool = False,
    split_file: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
) -> PrepareReport:
    """Read, retarget and derive every file of the sources; write the dataset.

    ``bvh_root`` is one BVH tree or several (or ``None``); ``amc_roots`` ASF/AMC trees;
    ``hdm05_roots`` HDM05 trees, the only way HDM05 takes are read. ``amc_fps`` is the
    frame rate of AMC takes whose name does not say it.

    Raises the first :class:`~posecast.errors.DataError` unless ``skip_bad``, in
    which case bad files are listed in the report and the manifest.
    """
    t0 = time.perf_counter()
    bvh_roots, amcs, hdms = _roots(bvh_root), _roots(amc_roots), _roots(hdm05_roots)
    if not (bvh_roots or amcs or hdms):
        raise DataError("no source directories given")
    files, sources = _gather(bvh_roots, amcs, hdms)
    table = load_split_table(split_file)
    parts: dict[str, list[Frames]] = {s: [] for s in SPLITS}
    clips: dict[str, list[dict[str, object]]] = {s: [] for s in SPLITS}
    stats = {s: SplitStats() for s in SPLITS}
    skipped: list[tuple[str, str]] = []
    used = [0] * len(sources)
    for path, source in files:
        try:
            clip, frames, rig = process_file(path, rigs, rig_name, amc_fps=amc_fps)
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
        entry: dict[str, object] = {
            "name": clip.name,
            "subject": subject,
            "rig": rig.name,
            "source": str(path),
            "frames": n,
            "format": "amc" if is_amc(path) else "bvh",
            "source_kind": sources[source]["kind"],
        }
        if is_amc(path):
            entry["skeleton"] = str(find_asf_for(path))
        clips[split].append(entry)
        used[source] += 1
        st = stats[split]
        st.sequences += 1
        st.frames += n
        st.contact_frames += int(frames["contacts"].sum())
        st.subjects.add(subject)
        if progress:
            progress(f"{split:5s} {path.name} ({rig.name}, {n} frames)")
    for src, n_clips in zip(sources, used, strict=True):
        src["clips"] = n_clips
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
        "source_root": str((bvh_roots or amcs or hdms)[0]),
        "sources": sources,
        # Whether HDM05 (CC BY-SA 3.0) went in: the model card must say so.
        "hdm05": any(n and src["kind"] == "hdm05" for src, n in zip(sources, used, strict=True)),
        "splits": {s: stats[s].as_dict(TARGET_FPS) for s in SPLITS},
        "clips": clips,
        "skipped": [{"file": f, "error": e} for f, e in skipped],
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    return PrepareReport(out, stats, skipped, time.perf_counter() - t0, sources=sources)
