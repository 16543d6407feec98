"""Engines on the shipped artifacts (posecast.online.inference.loader)."""

from __future__ import annotations

import pytest

from posecast.online.engine.config import EngineConfig
from posecast.online.inference.loader import kernels, load_engine, load_multi_engine
from posecast.tracking.layouts import Layout, spec
from posecast.tracking.sites import TrackerSet


def test_load_engine_serves_the_layout_it_was_asked_for() -> None:
    engine = load_engine(EngineConfig(samples=4, lookahead=1), layout=Layout.HMD3)
    assert engine.layout.layout is Layout.HMD3
    assert engine.layout == spec(Layout.HMD3)


def test_load_engine_says_which_backend_runs() -> None:
    cfg = EngineConfig(samples=4, lookahead=1)
    assert load_engine(cfg, backend="onnx").backend_name == "onnx"
    assert load_engine(cfg).backend_name in ("native", "onnx")  # native, or its fallback


def test_kernels_names_the_native_level_and_precision() -> None:
    assert kernels("onnx") == kernels("torch") == {"isa": "", "precision": "fp32"}
    native = pytest.importorskip("posecast.online.inference.native")
    before = native.native_precision().removesuffix("-emulated")
    try:
        native.set_native_precision("fp32")
        assert kernels("native") == {"isa": native.native_isa(), "precision": "fp32"}
        native.set_native_precision("bf16")
        want = "bf16" if native.native_isa() == "avx512bf16" else "bf16-emulated"
        assert kernels("native") == {"isa": native.native_isa(), "precision": want}
    finally:
        native.set_native_precision(before)


def test_load_multi_engine_builds_one_engine_per_layout_and_batches_each() -> None:
    multi = load_multi_engine(EngineConfig(samples=4, lookahead=1), tuple(Layout))
    assert set(multi.layouts) == set(Layout)
    multi.add_player("a", 1, Layout.HMD3)
    multi.add_player("b", 2, Layout.HMD3_WAIST)
    multi.add_player("c", 3, TrackerSet.parse("head,left_hand,right_hand,left_foot:imu"))
    assert multi.counts() == {Layout.HMD3_WAIST: 1, Layout.HMD3: 1, Layout.SITES: 1}
