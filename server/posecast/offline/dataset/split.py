"""The subject-wise train/val/test split.

The committed ``split.json`` lists each known subject's split: CMU subject numbers
and HDM05 actor codes (``bd``, ``bk``, ``dg``, ``mm``, ``tr``). A subject it does not
list (a user's own captures, the rest of the CMU release) is placed by a stable hash
of its id, 80 % train, 10 % val, 10 % test, so the same subject always lands in the
same split and no subject is ever in two.
"""

from __future__ import annotations

import hashlib
import json
import re
from importlib import resources
from pathlib import Path

from posecast.errors import ConfigError

SPLITS = ("train", "val", "test")


def load_split_table(path: str | Path | None = None) -> dict[str, str]:
    """Subject -> split from ``path``, or the committed table.

    Raises :class:`~posecast.errors.ConfigError` when ``path`` cannot be read, is not
    ``{"subjects": {subject: split}}`` or names a split other than train/val/test.
    """
    where = "posecast/offline/dataset/split.json" if path is None else str(path)
    if path is None:
        text = (resources.files("posecast.offline.dataset") / "split.json").read_text("utf-8")
    else:
        try:
            text = Path(path).read_text("utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read split table: {exc}") from exc
    try:
        table = json.loads(text)["subjects"]
        items = table.items()
    except (json.JSONDecodeError, TypeError, KeyError, AttributeError) as exc:
        raise ConfigError(f"{where}: not a split table ({exc!r})") from exc
    bad = {s: v for s, v in items if v not in SPLITS}
    if bad:
        raise ConfigError(f"{where}: unknown split names {bad}; use one of {list(SPLITS)}")
    return {str(k): str(v) for k, v in items}


def hashed_split(subject: str) -> str:
    bucket = int(hashlib.sha256(subject.encode("utf-8")).hexdigest()[:8], 16) % 10
    return "test" if bucket == 0 else "val" if bucket == 1 else "train"


def split_of(subject: str, table: dict[str, str]) -> str:
    return table.get(subject) or hashed_split(subject)


_CMU_NAME = re.compile(r"^(\d+)_(\d+)$")
_HDM05_NAME = re.compile(r"^HDM_([A-Za-z]+)_")


def subject_of(path: str | Path) -> str:
    """Performer id of a motion file, BVH or AMC.

    CMU trials ``SS_TT``: ``05_02.bvh.gz`` -> ``"5"``, ``135_02.amc.gz`` -> ``"135"``.
    HDM05 takes ``HDM_<actor>_...``: ``HDM_bd_squat1Reps_001_120.amc`` -> ``"bd"``
    (the actor code). Anything else: the folder name.
    """
    name = Path(path).name
    stem = name.split(".")[0]
    m = _CMU_NAME.match(stem)
    if m:
        return str(int(m.group(1)))
    h = _HDM05_NAME.match(name)
    if h:
        return h.group(1)
    return Path(path).parent.name or stem
