"""Writes ``recording.json``, the example page's desktop fallback: the demo's generated
12 s walk (``posecast demo``'s headsets) as headset and controller poses at 30 Hz, in
``@posecast/client``'s ``FrameInput`` shape (metres, orientations xyzw, posecast's frame).

    PYTHONPATH=server python client_sdk/typescript/examples/webxr-avatars/record.py
"""

from __future__ import annotations

import json
from pathlib import Path

from posecast.demo import motion
from posecast.tracking.features import TrackerSlot

frames = motion(None, seed=1)
KEYS = {
    "head": TrackerSlot.HEAD,
    "leftHand": TrackerSlot.LEFT_HAND,
    "rightHand": TrackerSlot.RIGHT_HAND,
}
out = [
    {
        key: {
            "position": [round(float(v), 4) for v in frames["tracker_pos"][i][slot]],
            "orientation": [round(float(v), 4) for v in frames["tracker_quat"][i][slot]],
        }
        for key, slot in KEYS.items()
    }
    for i in range(0, len(frames["tracker_pos"]), 2)  # 60 Hz -> 30 Hz
]
path = Path(__file__).with_name("recording.json")
path.write_text(json.dumps({"rate_hz": 30, "frames": out}, separators=(",", ":")) + "\n")
print(f"wrote {path} ({len(out)} frames)")
