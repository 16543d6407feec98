"""Acclaim AMC takes: :func:`read_amc` and :func:`parse_amc`, the motion of one take
on an :class:`~posecast.offline.motion.acclaim_asf.Asf` skeleton."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from posecast.errors import AcclaimError
from posecast.offline.motion.acclaim_asf import Asf
from posecast.offline.motion.acclaim_text import is_float, read_lines

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Amc:
    """A parsed AMC take: per bone, its dof values in the ASF's dof order."""

    values: dict[str, F64]  # bone name -> (F, len(dof)); absent bones are zeros
    frame_numbers: NDArray[np.int64]
    radians: bool
    source: str

    @property
    def n_frames(self) -> int:
        return int(self.frame_numbers.shape[0])


def read_amc(path: str | Path, asf: Asf) -> Amc:
    """Read an AMC take of ``asf``, plain or gzip-compressed."""
    return parse_amc(read_lines(path), asf, source=str(path))


def _parse_amc_fast(lines: Sequence[str], asf: Asf, source: str) -> Amc | None:
    """The common case in one vectorised pass: every frame lists the same bones in the
    same order, nothing else between them. ``None`` for anything else, which
    :func:`parse_amc` then reads line by line (and reports with its line)."""
    width = {b.name: len(b.dof) for b in asf.bones}
    radians = asf.angle_unit == "rad"
    start = None
    for i, raw in enumerate(lines):
        tok = raw.split()
        if not tok or tok[0][0] == "#":
            continue
        if tok[0][0] == ":":
            kw = tok[0].upper()
            radians = True if kw == ":RADIANS" else False if kw == ":DEGREES" else radians
            continue
        start = i
        break
    if start is None or not lines[start].strip().isdigit():
        return None
    names: list[str] = []
    for raw in lines[start + 1 :]:
        tok = raw.split()
        if not tok:
            continue
        if len(tok) == 1 and tok[0].isdigit():
            break
        if tok[0] not in width or tok[0] in names or len(tok) != width[tok[0]] + 1:
            return None
        names.append(tok[0])
    per_frame = 1 + sum(1 + width[nm] for nm in names)
    tokens = " ".join(lines[start:]).split()
    if len(tokens) % per_frame:
        return None
    table = np.array(tokens, dtype=object).reshape(-1, per_frame)
    value_cols: dict[str, list[int]] = {}
    col = 1
    for nm in names:
        if not (table[:, col] == nm).all():
            return None
        value_cols[nm] = list(range(col + 1, col + 1 + width[nm]))
        col += 1 + width[nm]
    try:
        numbers = table[:, 0].astype(np.int64)
        cols = [c for nm in names for c in value_cols[nm]]
        values = table[:, cols].astype(np.float64) if cols else np.zeros((len(table), 0))
    except ValueError:
        return None
    if (np.diff(numbers) != 1).any() or not np.isfinite(values).all():
        return None
    out: dict[str, F64] = {nm: np.zeros((len(table), w)) for nm, w in width.items()}
    k = 0
    for nm in names:
        out[nm] = np.ascontiguousarray(values[:, k : k + width[nm]])
        k += width[nm]
    return Amc(out, numbers, radians, source)


def parse_amc(lines: Sequence[str], asf: Asf, source: str = "<string>") -> Amc:
    """Parse AMC text split into lines. ``source`` names the file in error messages."""
    fast = _parse_amc_fast(lines, asf, source)
    if fast is not None:
        return fast
    width = {b.name: len(b.dof) for b in asf.bones}
    radians = asf.angle_unit == "rad"
    frames: list[int] = []
    # Per bone: the frame index, the values and the line of every line that gives it.
    at: dict[str, list[int]] = {nm: [] for nm in width}
    vals: dict[str, list[list[float]]] = {nm: [] for nm in width}
    where: dict[str, list[int]] = {nm: [] for nm in width}
    seen: set[str] = set()
    frame = -1
    for n, raw in enumerate(lines, start=1):
        tok = raw.split()
        if not tok:
            continue
        head = tok[0]
        if head[0] == "#":
            continue
        if head[0] == ":":
            kw = head.upper()
            if kw == ":RADIANS":
                radians = True
            elif kw == ":DEGREES":
                radians = False
            elif frames:
                raise AcclaimError(f"{head!r} after the first frame", file=source, line=n)
            continue
        if len(tok) == 1 and head.isdigit():
            number = int(head)
            if frames and number != frames[-1] + 1:
                raise AcclaimError(
                    f"frame {number} follows frame {frames[-1]} (frames must be consecutive)",
                    file=source,
                    line=n,
                )
            frames.append(number)
            frame += 1
            seen = set()
            continue
        if not frames:
            raise AcclaimError(
                f"expected a frame number, found {head!r} (not an AMC file?)",
                file=source,
                line=n,
            )
        w = width.get(head)
        if w is None:
            raise AcclaimError(f"unknown bone {head!r} (not in the ASF)", file=source, line=n)
        if head in seen:
            raise AcclaimError(
                f"bone {head!r} appears twice in frame {frames[-1]}", file=source, line=n
            )
        seen.add(head)
        if len(tok) != w + 1:
            raise AcclaimError(
                f"bone {head!r}: expected {w} value(s), found {len(tok) - 1}", file=source, line=n
            )
        try:
            row = [float(t) for t in tok[1:]]
        except ValueError:
            bad = next(t for t in tok[1:] if not is_float(t))
            raise AcclaimError(
                f"bone {head!r}: {bad!r} is not a number", file=source, line=n
            ) from None
        at[head].append(frame)
        vals[head].append(row)
        where[head].append(n)
    if not frames:
        raise AcclaimError("no frames (not an AMC file?)", file=source, line=max(1, len(lines)))
    out: dict[str, F64] = {}
    for nm, w in width.items():
        arr = np.zeros((len(frames), w), dtype=np.float64)
        if w and at[nm]:
            given = np.asarray(vals[nm], dtype=np.float64)
            finite = np.isfinite(given).all(axis=1)
            if not finite.all():
                n = where[nm][int(np.argmin(finite))]
                raise AcclaimError(f"bone {nm!r}: non-finite value", file=source, line=n)
            arr[np.asarray(at[nm])] = given
        out[nm] = arr
    return Amc(out, np.asarray(frames, dtype=np.int64), radians, source)
