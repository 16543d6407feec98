"""proto/'s Python helpers (not a package: loaded from their files) and its vectors."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

PROTO = Path(__file__).resolve().parents[2] / "proto"


def load(name: str) -> ModuleType:
    """``proto/<name>.py`` as a module (its own folder first on the path, as when run)."""
    if name in sys.modules:
        return sys.modules[name]
    sys.path.insert(0, str(PROTO))
    try:
        spec = importlib.util.spec_from_file_location(name, PROTO / f"{name}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(PROTO))
    return module


def cases() -> list[dict[str, Any]]:
    """Every case of every ``proto/vectors/*.json``."""
    return [
        c for f in sorted((PROTO / "vectors").glob("*.json")) for c in json.loads(f.read_text())
    ]
