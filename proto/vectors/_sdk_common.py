"""What the SDK behaviour tables (``proto/vectors/sdk/``) share: the joint count, unit
quaternions, and the JSON layout of ``interp.json``, ``conventions.json`` and
``clock.json`` (``delay.json`` has its own, one step per line: ``_sdk_delay.py``)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.skeleton import Joint

F64 = NDArray[np.float64]
J = len(Joint)


def unit(q: F64) -> F64:
    out: F64 = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out


def render(obj: Any) -> str:
    """JSON with one line per object field; a list of numbers (or of number lists, a
    pose's array) stays on one line."""
    return _render(obj, 0) + "\n"


def _flat(v: Any) -> bool:
    return isinstance(v, list) and all(
        isinstance(x, int | float) or (isinstance(x, list) and _flat(x)) for x in v
    )


def _render(v: Any, depth: int) -> str:
    pad, inner = " " * depth, " " * (depth + 1)
    if isinstance(v, dict) and v:
        items = [f"{inner}{json.dumps(k)}: {_render(x, depth + 1)}" for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(v, list) and v and not _flat(v):
        return "[\n" + ",\n".join(inner + _render(x, depth + 1) for x in v) + "\n" + pad + "]"
    return json.dumps(v, separators=(",", ":")) if isinstance(v, list) else json.dumps(v)
