"""The body package sits below both online and offline: importing every module of it
loads nothing of ``posecast.online`` or ``posecast.offline``, and no inference library
or I/O shell (the native kernels arrive through a backend's pool, by name)."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import posecast.body

MODULES = sorted(f"posecast.body.{m.name}" for m in pkgutil.iter_modules(posecast.body.__path__))

CODE = """
import sys
for blocked in ("onnxruntime", "onnx", "torch", "websockets", "redis", "posecast._native"):
    sys.modules[blocked] = None  # any import of these now fails
for name in sys.argv[1:]:
    __import__(name)
loaded = sorted(m for m in sys.modules if m.startswith(("posecast.online", "posecast.offline")))
print("loaded:", loaded)
"""


def test_the_body_imports_neither_online_nor_offline_nor_an_inference_library() -> None:
    assert "posecast.body.pipeline" in MODULES and len(MODULES) >= 10
    out = subprocess.run(
        [sys.executable, "-c", CODE, *MODULES], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "loaded: []"
