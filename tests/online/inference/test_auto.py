"""Backends by name (posecast.online.inference.auto): the native fallback and bad names
(torch against ONNX Runtime is ``test_torch_backend.py``'s)."""

from __future__ import annotations

import logging
import sys

import pytest

from posecast.errors import ConfigError
from posecast.online.engine.config import EngineConfig
from posecast.online.inference.auto import load_backend
from posecast.online.inference.loader import load_multi_engine
from posecast.tracking.layouts import Layout

pytest.importorskip("torch")
pytest.importorskip("onnx")


def test_native_falls_back_to_onnx_with_one_warning(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Where the native adapter cannot load, both models of a server run onnx, and one
    warning line says why."""
    monkeypatch.setitem(sys.modules, "posecast.online.inference.native", None)
    with caplog.at_level(logging.WARNING, logger="posecast.engine"):
        multi = load_multi_engine(EngineConfig(samples=2, lookahead=1), tuple(Layout))
    assert multi.backends == {str(k): "onnx" for k in Layout}
    warnings = [r for r in caplog.records if r.name == "posecast.engine"]
    assert len(warnings) == 1 and warnings[0].levelno == logging.WARNING
    message = warnings[0].getMessage()
    assert "native backend unavailable" in message and "sys.modules" in message
    assert "onnx" in message


def test_an_unknown_backend_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="unknown backend 'cuda'") as e:
        load_backend("cuda")
    assert any("native, onnx, torch" in n for n in e.value.__notes__)


def test_torch_without_torch_is_a_config_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ConfigError, match="needs the 'torch' package") as e:
        load_backend("torch")
    assert any("posecast[train]" in n for n in e.value.__notes__)
