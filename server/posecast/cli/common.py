"""What the ``posecast`` commands share: the error a user's mistake raises (a
:class:`~posecast.errors.PosecastError` with a hint, which :func:`posecast.cli.main`
prints), and the checks made at the edge, before a command starts its work: option
values, output paths, optional packages, prepared datasets and checkpoints."""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from posecast.errors import ConfigError, DatasetError, ModelError, PosecastError
from posecast.tracking.layouts import Layout

if TYPE_CHECKING:  # the data stack loads only for the commands that need it
    from posecast.offline.dataset.store import SplitData

HINT = "hint: "  # the note that carries an error's hint (main prints it so)
_E = TypeVar("_E", bound=PosecastError)


def hinted(exc: _E, hint: str) -> _E:
    """``exc`` with the hint :func:`posecast.cli.main` prints under it."""
    exc.add_note(HINT + hint)
    return exc


def config_error(message: str, hint: str) -> ConfigError:
    """A command-line mistake (``CONFIG_INVALID``) with its hint."""
    return hinted(ConfigError(message), hint)


def add_defaulted(
    parser: argparse.ArgumentParser, flag: str, default: str | float, text: str, more: str = ""
) -> None:
    """Add the option ``flag`` of ``default``'s type (str, int or float) with its help
    ``text``, which ``--help`` ends with the default and ``more``: ``text (default 3.0)``,
    or with ``more="; 0: off"``, ``text (default 3.0; 0: off)``."""
    parser.add_argument(
        flag, type=type(default), default=default, help=f"{text} (default %(default)s{more})"
    )


# --- Validation at the edge ----------------------------------------------------------


def given(args: argparse.Namespace, names: Iterable[str]) -> dict[str, Any]:
    """The options among ``names`` that ``args`` holds and that were given (``None``:
    the config's own default stands), by name, for a config built from its fields."""
    out = {n: getattr(args, n, None) for n in names}
    return {n: v for n, v in out.items() if v is not None}


def at_least(option: str, value: float, low: float, command: str) -> None:
    if not value >= low:  # NaN fails too
        raise config_error(
            f"{option} {value} must be >= {low:g}", f"see `posecast {command} --help`"
        )


def check_samples(option: str, values: Sequence[int], command: str) -> None:
    """Latent sample counts N: 1 to the engine's MAX_SAMPLES (a larger N would stop the
    run later with a MemoryError traceback)."""
    from posecast.online.engine.config import MAX_SAMPLES

    for n in values:
        at_least(option, n, 1, command)
        if n > MAX_SAMPLES:
            raise config_error(
                f"{option} {n} must be <= {MAX_SAMPLES}",
                f"N = 100 is what the server runs; see `posecast {command} --help`",
            )


def finite(option: str, value: float, command: str, *, positive: bool = False) -> None:
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        wanted = "a finite number > 0" if positive else "a finite number >= 0"
        raise config_error(f"{option} {value} must be {wanted}", f"see `posecast {command} --help`")


def _float_arg(option: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value < 0:
        raise config_error(f"{option} {text!r} must be a finite number >= 0", "e.g. 1.0, or `off`")
    return value


def float_or_off(option: str, text: str | None, default: float | None) -> float | None:
    """An option given as a number >= 0 or `off` (``None``); ``default`` when absent."""
    if text is None:
        return default
    return None if text == "off" else _float_arg(option, text)


def int_list(option: str, text: str, command: str) -> list[int]:
    """A comma-separated list of distinct integers >= 1 (``"1,10,100"``)."""
    try:
        values = [int(p) for p in text.split(",")]
    except ValueError:
        values = []
    if not values or min(values) < 1:
        raise config_error(
            f"{option} {text!r} is not a comma-separated list of integers >= 1",
            f"e.g. {option} 1,10,100",
        )
    twice = [v for i, v in enumerate(values) if v in values[:i]]
    if twice:  # the same count measured twice: two figures for one row
        raise config_error(
            f"{option} {text!r} names {twice[0]} twice: each count once",
            f"e.g. {option} 1,10,100",
        )
    return values


def backend_names(option: str, text: str, command: str, *, many: bool = False) -> list[str]:
    """Backend names (``native``, ``onnx``, ``torch``); with ``many``, a comma-separated
    list of distinct ones (``"native,onnx"``)."""
    from posecast.online.engine.ports import BACKENDS

    names = [n.strip() for n in text.split(",")] if many else [text]
    if not all(n in BACKENDS for n in names) or len(set(names)) < len(names):
        what = "a comma-separated list of distinct backends" if many else "a backend"
        raise config_error(
            f"{option} {text!r} is not {what}",
            f"use {'some' if many else 'one'} of {', '.join(BACKENDS)}, e.g. {option} "
            f"{'native,onnx' if many else 'onnx'} (`posecast {command} --help`)",
        )
    return names


def check_json_out(path: Path | None) -> None:
    """Fail now, not after a long run, when the report could not be written."""
    if path is None:
        return
    if path.is_dir():
        raise config_error(
            f"--json {path} is a directory", "name the file to write, e.g. report.json"
        )
    if not path.parent.is_dir():
        raise config_error(
            f"--json {path}: directory {path.parent} does not exist", "create it or pick another"
        )


def check_out_dir(option: str, path: Path) -> None:
    """Fail now, not with a traceback at the first write, when the output directory
    cannot be made: the path, or a folder above it, is a file, or the nearest folder
    that exists is not writable."""
    if path.exists() and not path.is_dir():
        raise config_error(
            f"{option} {path} exists and is not a directory", "pick a directory path"
        )
    at = path.absolute()
    while not at.exists():
        at = at.parent
    if not at.is_dir():
        raise config_error(
            f"{option} {path}: {at} is a file, not a directory", "pick a directory path"
        )
    if not os.access(at, os.W_OK | os.X_OK):
        raise config_error(
            f"{option} {path}: cannot write in {at}", "pick a directory you may write in"
        )


def check_models_dir(path: Path | None, option: str = "--models") -> None:
    if path is not None and not path.is_dir():
        raise hinted(
            ModelError("no such models directory", path=path),
            f"pass the directory `posecast export --out` wrote, or leave out {option} "
            "for the shipped models",
        )


def need(extra: str, *modules: str) -> None:
    """Fail with the install line when an optional dependency is missing."""
    import importlib.util

    for mod in modules:
        if importlib.util.find_spec(mod) is None:
            raise config_error(
                f"this command needs the {mod!r} package (posecast[{extra}])",
                f"pip install 'posecast[{extra}]'",
            )


def dataset_manifest(path: Path) -> dict[str, object]:
    """The manifest of a prepared dataset (:class:`DatasetError` if it is not one)."""
    from posecast.offline.dataset.store import read_manifest

    if not path.is_dir():
        raise DatasetError("no such dataset directory", path=path)
    return read_manifest(path)


def dataset_split(path: Path, name: str, verb: str) -> SplitData:
    """The clips of split ``name`` of a prepared dataset (a :class:`DatasetError` with a
    hint to ``verb`` another split if it has none)."""
    from posecast.offline.dataset.split import SPLITS
    from posecast.offline.dataset.store import load_split

    dataset_manifest(path)
    split = load_split(path, name)
    if split.n_clips == 0:
        raise hinted(
            DatasetError(f"the {name} split has no clips", path=path),
            f"{verb} another --split (one of {', '.join(SPLITS)})",
        )
    return split


def _clip_frames(manifest: dict[str, object], split: str, path: Path) -> list[int]:
    """Frame counts of the clips of one split, from the manifest."""
    clips = manifest.get("clips")
    entries = clips.get(split) if isinstance(clips, dict) else None
    if not isinstance(entries, list):
        raise DatasetError(f"manifest lists no {split} split", path=path)
    try:
        return [int(c["frames"]) for c in entries]
    except (TypeError, KeyError, ValueError):
        raise DatasetError(f"manifest: bad clip entry in the {split} split", path=path) from None


def need_clips(manifest: dict[str, object], path: Path, splits: Sequence[str], frames: int) -> None:
    for split in splits:
        if not any(n >= frames for n in _clip_frames(manifest, split, path)):
            raise hinted(
                DatasetError(
                    f"the {split} split has no clip of at least {frames} frames", path=path
                ),
                "prepare more data, or move subjects into that split with "
                "`posecast data prepare --split-file FILE`",
            )


def check_checkpoint(
    option: str, path: Path, kind: str, layout: str | None = None, hint: str | None = None
) -> None:
    """Check that ``path`` is a checkpoint of ``kind`` (and tracker ``layout``)."""
    import pickle

    from posecast.offline.train.checkpoint import load_checkpoint

    how = f"posecast train {kind}" + (
        f" --layout {layout}" if layout in (Layout.HMD3, Layout.SITES) else ""
    )
    hint = hint or f"pass a checkpoint.pt written by `{how}` to {option}"
    if not path.is_file():
        raise hinted(ModelError("no such checkpoint file", path=path), hint)
    try:
        state: Any = load_checkpoint(path)
    except (OSError, EOFError, RuntimeError, ValueError, pickle.UnpicklingError) as exc:
        raise hinted(ModelError(f"not a checkpoint: {exc}", path=path), hint) from None
    if not isinstance(state, dict) or not {"model", "norm", "config"} <= state.keys():
        raise hinted(ModelError("not a posecast checkpoint", path=path), hint)
    if state.get("kind") != kind:
        raise hinted(
            ModelError(f"a {state.get('kind')!r} checkpoint, not {kind!r}", path=path), hint
        )
    if layout is not None:
        config = state["config"]
        got = (
            str(config.get("layout", Layout.HMD3_WAIST.value)) if isinstance(config, dict) else None
        )
        if got != layout:
            raise hinted(
                ModelError(f"a checkpoint of layout {got!r}, not {layout!r}", path=path), hint
            )
