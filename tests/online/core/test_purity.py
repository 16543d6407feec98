"""The core and the engine are pure: importing them loads no inference library and no
asyncio shell (the engine's decoder arrives built, from inference/loader.py)."""

from __future__ import annotations

import subprocess
import sys

CODE = """
import sys
for blocked in ("onnxruntime", "torch", "websockets", "redis"):
    sys.modules[blocked] = None  # any import of these now fails
import posecast.online.core.hub
import posecast.online.core.session
import posecast.online.core.admission
import posecast.online.core.routing
import posecast.online.core.cluster_sink
import posecast.online.core.tick
import posecast.online.engine.types
import posecast.online.engine.ssi
import posecast.online.engine.multi
loaded = sorted(m for m in sys.modules if m.startswith("posecast.online.inference")
                or m.startswith("posecast.online.shell"))
print("loaded:", loaded)
"""


def test_core_and_engine_import_with_onnxruntime_torch_websockets_and_redis_blocked() -> None:
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "loaded: []"
