"""Write the XR avatars sample's recording: the Python SDK's built-in walk as tracker
frames, the text format TrackerRecording.cs reads.

    .venv/bin/python client_sdk/csharp/Tests~/make_recording.py

rewrites Samples~/XRAvatars/Resources/posecast-walk.csv.
"""

from __future__ import annotations

from pathlib import Path

from posecast_client import WalkSource

OUT = (
    Path(__file__).resolve().parent.parent
    / "Samples~"
    / "XRAvatars"
    / "Resources"
    / "posecast-walk.csv"
)
HEADER = (
    "# posecast tracker recording v1: the Python SDK's WalkSource(seconds=8, seed=0) at 60 Hz.\n"
    "# One frame a line: t_s, valid, then per slot (HEAD, LEFT_HAND, RIGHT_HAND, WAIST)\n"
    "# px py pz (metres) qx qy qz qw, posecast's frame (right-handed, +Y up, the floor at y = 0).\n"
)


def main() -> None:
    walk = WalkSource(seconds=8.0, seed=0)
    lines = [HEADER.rstrip("\n")]
    for k, sample in enumerate(walk.samples()):
        row = [f"{k / 60.0:.4f}", str(sample.valid)]
        for p, q in zip(sample.positions, sample.orientations, strict=True):
            row += [f"{v:.4f}" for v in p] + [f"{v:.5f}" for v in q]
        lines.append(",".join(row))
    OUT.write_text("\n".join(lines) + "\n", "utf-8")
    print(f"wrote {OUT} ({len(lines) - 1} frames)")


if __name__ == "__main__":
    main()
