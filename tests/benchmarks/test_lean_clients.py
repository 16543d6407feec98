"""``benchmarks/lean_clients.py``, the ramp's load generator: its v2 record counting
against the shared wire vectors, and a short real run of each protocol against a real
``posecast serve`` (a few players, a few seconds: every pose delivered and counted;
no timing bounds, the figures are ``load.py``'s to measure)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

import lean_clients  # noqa: E402
import load_rig  # noqa: E402

sys.path.remove(str(REPO / "benchmarks"))


def _cases() -> list[dict[str, Any]]:
    cases: list[dict[str, Any]] = json.loads((REPO / "proto/vectors/poses.json").read_text())
    return [c for c in cases if "messages" in c]


def test_records_are_counted_as_the_vectors_decode_them() -> None:
    mod: ModuleType = lean_clients
    counted = 0
    for case in _cases():
        if "error" in case:
            continue
        for message, expect in zip(case["messages"], case["expect"], strict=True):
            data = mod.poses_data(bytes.fromhex(message))
            assert data is not None, case["description"]
            assert mod.count_records(data) == len(expect), case["description"]
            counted += len(expect)
    assert counted > 20  # keyframes and deltas of several cases were walked


def test_records_cut_short_are_refused() -> None:
    cut = [c for c in _cases() if "cut short" in c["description"]]
    assert len(cut) == 2
    for case in cut:
        data = lean_clients.poses_data(bytes.fromhex(case["messages"][-1]))
        assert data is not None
        with pytest.raises(ValueError, match="cut short"):
            lean_clients.count_records(data)


def test_other_messages_are_not_poses() -> None:
    assert lean_clients.poses_data(lean_clients._p({"type": "presence", "room": "r"})) is None
    # A poses message written another way (keys out of the server's order) still reads.
    odd = lean_clients._p({"data": b"", "type": "poses", "t": 1.0})
    assert lean_clients.poses_data(odd) == b""


@pytest.mark.parametrize("protocol", [1, 2])
def test_a_short_run_receives_every_pose(tmp_path: Path, protocol: int) -> None:
    with load_rig.serve(10, tmp_path) as server:
        lean = load_rig.LeanClients.start(server, tmp_path, 3, protocol=protocol)
        try:
            added = lean.add(6, 30.0)
            assert added["joined"] == 6 and added["failed"] == {}, added
            time.sleep(1.0)  # past the first poses
            a = lean.stats()
            time.sleep(3.0)
            b = lean.stats()
        finally:
            final = lean.stop()
    assert a["protocol"] == protocol
    assert [row[3] for row in b["players"]] == [3] * 6  # rooms of 3, from welcome
    w = load_rig.lean_window(a, b)
    assert w["client_errors"] == 0 and b["error_codes"] == [], b
    assert b["connection_losses"] == 0 and final["connection_losses"] == 0
    # Delivered share near 100 %: what the server sent is what was counted (a share, not
    # a time: a slow machine sends fewer frames and expects fewer poses alike).
    assert 0.9 <= w["delivery"] <= 1.05, w
    assert w["delivery_worst"] >= 0.85, w
