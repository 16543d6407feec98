"""Write the protocol test vectors (v1 and v2) (``proto/vectors/*.json``) and ``proto/errors.json``.

    .venv/bin/python proto/vectors/generate.py           # rewrite the files
    .venv/bin/python proto/vectors/generate.py --check   # exit 1 if they are stale

Valid cases are built as typed messages and encoded with the codec, so
``canonical_hex`` is reproducible; their ``also_accept_hex`` come from the small
msgpack writer in ``_writer.py``, which can choose float32, wide ints, 16-bit
headers, another key order, nil optionals and unknown fields. The cases themselves
are in ``_cases_session.py`` (envelope, hello, welcome, presence, kick, ping, pong,
error, bye), ``_cases_motion.py`` (calibrate, frame, pose, selector) and
``_cases_v2.py`` (what v2 adds, including the pose-record streams). Every case lists
the protocol ``versions`` it holds in (the generator checks each one). Each
invalid case breaks one rule, so its code does not depend on the order a decoder
checks fields in beyond the envelope order the spec fixes.

Building a case also checks it against the codec (canonical bytes, every accepted
encoding, every expected error), so a generator run is itself a test. The vectors
are committed; ``tests/online/protocol/test_vectors.py`` checks them against this script.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the helper modules beside this script

import _cases_motion as motion  # noqa: E402
import _cases_session as session  # noqa: E402
import _cases_v2 as v2  # noqa: E402
from _writer import render  # noqa: E402

from posecast.errors import ProtocolError  # noqa: E402

FILES = {
    "envelope": lambda: session.envelope_cases() + v2.envelope_cases(),
    "hello": lambda: session.hello_cases() + v2.hello_cases(),
    "welcome": lambda: session.welcome_cases() + v2.welcome_cases(),
    "calibrate": motion.calibrate_cases,
    "frame": motion.frame_cases,
    "pose": motion.pose_cases,
    "presence": lambda: session.presence_cases() + v2.presence_cases(),
    "selector": motion.selector_cases,
    **{
        name: (lambda name=name: session.small_cases()[name])
        for name in ("kick", "ping", "pong", "error", "bye")
    },
    "poses": v2.poses_cases,
    "skeleton": v2.skeleton_cases,
    "pose_rate": v2.pose_rate_cases,
    "forecast": v2.forecast_cases,
    "resync": v2.resync_cases,
}


def build() -> dict[str, list[dict[str, Any]]]:
    """Every vector file's cases, by file name."""
    files = {f"{name}.json": fn() for name, fn in FILES.items()}
    names = [c["name"] for cases in files.values() for c in cases]
    assert len(names) == len(set(names)), "vector names must be unique"
    return files


def error_table(files: dict[str, list[dict[str, Any]]]) -> str:
    """``proto/errors.json``: every wire code from ``posecast.errors``, in class order.

    ``decoder`` marks the codes a decoder itself produces (those the vectors use);
    the rest come from the server's session logic.
    """
    used = {c["error"] for cases in files.values() for c in cases if "error" in c}
    rows = [
        {
            "code": cls.code,
            "fatal": cls.fatal,
            "decoder": cls.code in used,
            "meaning": " ".join((cls.__doc__ or "").replace("``", "").split()),
        }
        for cls in ProtocolError.__subclasses__()
    ]
    assert used <= {r["code"] for r in rows}, used
    return json.dumps(rows, indent=1, ensure_ascii=False) + "\n"


def main(argv: list[str]) -> int:
    stale = []
    files = build()
    outputs = {HERE / name: render(cases) for name, cases in files.items()}
    outputs[HERE.parent / "errors.json"] = error_table(files)
    for path, text in outputs.items():
        fname = path.name
        if "--check" in argv:
            if not path.exists() or path.read_text() != text:
                stale.append(fname)
        else:
            path.write_text(text)
    if stale:
        print("stale vector files:", ", ".join(stale), file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
