"""Write the SDK behaviour tables ``proto/vectors/sdk/interp.json``, ``delay.json``,
``conventions.json`` and ``clock.json``.

    .venv/bin/python proto/vectors/generate_sdk.py           # rewrite the files
    .venv/bin/python proto/vectors/generate_sdk.py --check   # exit 1 if they are stale

These are not wire vectors (the codec readers glob ``proto/vectors/*.json``, so they
live one folder down): they pin what both SDKs do with decoded poses. Each table is
built by a module beside this script, whose docstring says what its cases hold:

* ``interp.json``: the jitter buffer at a fixed delay, expected poses worked out from
  the rules with other math than the SDKs use (``_sdk_interp.py``);
* ``delay.json``: the adaptive render delay on simulated arrival sequences
  (``_sdk_delay.py``);
* ``conventions.json``: each engine's frame, poses converted into it, the WebXR view
  turn and the joint -> bone-name table (``_sdk_conventions.py``);
* ``clock.json``: ``ClockSync``'s display clock, the Python SDK's own values with the
  rule each query exercises (``_sdk_clock.py``).

``_sdk_common.py`` holds what they share (the joint count, unit quaternions, the JSON
layout).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the helper modules beside this script
from _sdk_clock import clock  # noqa: E402
from _sdk_common import render  # noqa: E402
from _sdk_conventions import conventions  # noqa: E402
from _sdk_delay import render_delay_table  # noqa: E402
from _sdk_interp import interp  # noqa: E402

OUT = HERE / "sdk"


def main(argv: list[str]) -> int:
    outputs = {
        OUT / "interp.json": render(interp()),
        OUT / "delay.json": render_delay_table(),
        OUT / "conventions.json": render(conventions()),
        OUT / "clock.json": render(clock()),
    }
    stale = []
    for path, text in outputs.items():
        if "--check" in argv:
            if not path.exists() or path.read_text() != text:
                stale.append(path.name)
        else:
            path.parent.mkdir(exist_ok=True)
            path.write_text(text)
    if stale:
        print("stale SDK vector files:", ", ".join(stale), file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
