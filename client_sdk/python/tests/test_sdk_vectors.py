"""The SDK behaviour tables themselves (``proto/vectors/sdk/``): fresh from their
generator, and well formed. The SDKs run them in test_interp.py / test_conventions.py
(and ``client_sdk/typescript/test/interp.test.ts`` / ``conventions.test.ts``)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

VECTORS = Path(__file__).resolve().parents[3] / "proto" / "vectors"
pytestmark = pytest.mark.skipif(
    not (VECTORS / "generate_sdk.py").exists(), reason="proto/vectors not found (repo only)"
)


def test_tables_are_what_the_generator_writes() -> None:
    pytest.importorskip("posecast.geometry.rotations")  # the generator's reference maths
    spec = importlib.util.spec_from_file_location("generate_sdk", VECTORS / "generate_sdk.py")
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    assert gen.main(["--check"]) == 0, "run: .venv/bin/python proto/vectors/generate_sdk.py"


def test_tables_are_well_formed() -> None:
    interp = json.loads((VECTORS / "sdk" / "interp.json").read_text("utf-8"))
    names = [c["name"] for c in interp["cases"]]
    assert len(names) == len(set(names))
    modes = set()
    for case in interp["cases"]:
        assert any("query" in s for s in case["steps"]), case["name"]
        for step in case["steps"]:
            assert ("push" in step) != ("query" in step)
            if "push" in step:
                assert len(step["push"]["positions"]) == 19
            elif step["expect"] is not None:
                modes.add(step["expect"]["mode"])
    assert modes == {"interpolate", "extrapolate", "hold"}  # every rule is exercised
    delay = json.loads((VECTORS / "sdk" / "delay.json").read_text("utf-8"))
    names = [c["name"] for c in delay["cases"]]
    assert len(names) == len(set(names))
    for case in delay["cases"]:
        cfg, prev = case["config"], None
        for step in case["steps"]:
            assert ("push" in step) != ("query" in step)
            if "query" not in step or step["expect"] is None:
                continue
            e = step["expect"]
            assert e["mode"] in {"interpolate", "extrapolate", "hold"}
            if not cfg["adaptive"]:
                assert e["delay_s"] == cfg["delay_s"] and e["target_s"] is None
                continue
            assert cfg["min_delay_s"] - 1e-12 <= e["delay_s"] <= cfg["max_delay_s"] + 1e-12
            if prev is not None and step["query"] > prev[0]:  # the slew bound, time forward
                dt = step["query"] - prev[0]
                assert abs(e["delay_s"] - prev[1]) <= cfg["delay_slew"] * dt + 1e-9, case["name"]
                assert e["t"] > prev[2], case["name"]  # the shown time goes on
            if prev is None or step["query"] > prev[0]:
                prev = (step["query"], e["delay_s"], e["t"])
    conv = json.loads((VECTORS / "sdk" / "conventions.json").read_text("utf-8"))
    assert {c["engine"] for c in conv["cases"]} == set(conv["engines"])
    assert len(conv["bones"]) == 19
