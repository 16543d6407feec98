"""Engine conventions: the shared table ``proto/vectors/sdk/conventions.json``, the
inverses, and the quaternion rule checked against the rotation matrices it stands for."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import posecast_client as pc
from posecast_client.conventions import (
    BONE_RIGS,
    BONES,
    FRAMES,
    Engine,
    engine2pos,
    engine2quat,
    head2xrview_quat,
    pos2engine,
    pose2engine,
    quat2engine,
)
from posecast_client.rotations import quat2mat

TABLE = Path(__file__).resolve().parents[3] / "proto" / "vectors" / "sdk" / "conventions.json"
VECTORS: dict[str, Any] = json.loads(TABLE.read_text("utf-8")) if TABLE.exists() else {}
needs_table = pytest.mark.skipif(not VECTORS, reason="proto/vectors/sdk not found (repo only)")


def same_rotations(got: np.ndarray, want: np.ndarray, tol: float) -> bool:
    err = np.minimum(np.abs(got - want).max(-1), np.abs(got + want).max(-1))
    return bool(err.max() <= tol)


@needs_table
@pytest.mark.parametrize("case", VECTORS.get("cases", []), ids=lambda c: c["name"])
def test_conventions_vector(case: dict[str, Any]) -> None:
    tol = VECTORS["tolerance"]
    out = pose2engine(case["positions"], case["rotations"], case["engine"])
    np.testing.assert_allclose(out.positions, case["expect_positions"], atol=tol["position"])
    assert out.rotations is not None
    assert same_rotations(out.rotations, np.array(case["expect_rotations"]), tol["rotation"])
    # ... and back.
    np.testing.assert_allclose(
        engine2pos(case["expect_positions"], case["engine"]), case["positions"], atol=1e-9
    )
    back = engine2quat(case["expect_rotations"], case["engine"])
    assert same_rotations(back, np.array(case["rotations"]), 1e-9)


@needs_table
def test_frames_match_the_table() -> None:
    for name, frame in VECTORS["engines"].items():
        ours = FRAMES[Engine(name)]
        np.testing.assert_allclose(ours.matrix, frame["basis"], atol=1e-12)
        assert (ours.scale, ours.right_handed) == (frame["scale"], frame["right_handed"])
    assert set(VECTORS["engines"]) == {e.value for e in Engine}


@needs_table
def test_head_to_xr_view_vectors() -> None:
    for row in VECTORS["head2xrview"]:
        got = head2xrview_quat(row["head"])
        assert same_rotations(got[None], np.array([row["view"]]), VECTORS["tolerance"]["rotation"])


@needs_table
def test_bone_names_match_the_table() -> None:
    rows = VECTORS["bones"]
    assert [r["joint"] for r in rows] == list(pc.JOINT_NAMES)
    for rig in BONE_RIGS:
        assert [BONES[rig][pc.Joint[r["joint"]]] for r in rows] == [r[rig] for r in rows], rig
        assert len(set(BONES[rig].values())) == len(pc.Joint), f"{rig}: a bone used twice"


@pytest.mark.parametrize("engine", list(Engine))
def test_quaternion_rule_is_the_matrix_change_of_basis(
    engine: Engine, rng: np.random.Generator
) -> None:
    """``R_engine = M R M^T`` for the basis ``M``; positions rotate along with it."""
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    m = FRAMES[engine].matrix
    want = m @ quat2mat(q) @ m.T
    np.testing.assert_allclose(quat2mat(quat2engine(q, engine)), want, atol=1e-12)
    # A bone vector turned in posecast, converted, equals the converted vector turned there.
    v = rng.normal(size=(50, 3))
    turned = np.einsum("nij,nj->ni", quat2mat(q), v)
    there = np.einsum("nij,nj->ni", quat2mat(quat2engine(q, engine)), pos2engine(v, engine))
    np.testing.assert_allclose(pos2engine(turned, engine), there, atol=1e-9)


def test_positions_only_poses_convert_without_rotations() -> None:
    out = pose2engine(np.zeros((19, 3)), None, "unreal")
    assert out.rotations is None and out.positions.shape == (19, 3)


def test_unknown_engine_is_refused() -> None:
    with pytest.raises(ValueError):
        pos2engine([0.0, 0.0, 1.0], "godot")


def test_the_docs_bone_table_is_the_sdk_table() -> None:
    """docs/game-engines.md's bone table says what BONES holds, row for row."""
    doc = Path(__file__).resolve().parents[3] / "docs" / "game-engines.md"
    if not doc.exists():
        pytest.skip("docs/game-engines.md not found (repo only)")
    rows = [
        [cell.strip() for cell in line.strip("|").split("|")]
        for line in doc.read_text("utf-8").splitlines()
        if line.startswith("| ") and line.split("|")[1].strip() in pc.JOINT_NAMES
    ]
    assert [r[0] for r in rows] == list(pc.JOINT_NAMES)
    for r in rows:
        assert r[1:] == [BONES[rig][pc.Joint[r[0]]] for rig in BONE_RIGS], r[0]
