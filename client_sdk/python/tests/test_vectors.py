"""Run every case of ``proto/vectors/*.json`` against the SDK's own codec.

Each case runs in every protocol version it lists. Valid cases: the canonical bytes
decode, re-encode to themselves byte for byte and match the case's ``message``;
every ``also_accept_hex`` decodes and re-encodes to the canonical bytes. Invalid
cases fail with exactly their code (and field). Stream cases (v2 pose records) are
decoded message by message by the SDK's own record decoder, which is written apart
from the server's encoder: the independent check of the generator's bytes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from posecast_client.codec import FIELDS, V1_TYPES, V2_TYPES, decode, encode, to_wire
from posecast_client.errors import ProtocolError
from posecast_client.protocol import Poses
from posecast_client.records import ROOT_UNIT_M, AvatarState, decode_records, skeleton2offsets

PROTO = Path(__file__).resolve().parents[3] / "proto"
VECTOR_FILES = sorted((PROTO / "vectors").glob("*.json"))
CASES = [c for f in VECTOR_FILES for c in json.loads(f.read_text("utf-8"))]
VALID = [pytest.param(v, c, id=f"v{v}-{c['name']}") for c in CASES if "message" in c
         for v in c["versions"]]  # fmt: skip
INVALID = [pytest.param(v, c, id=f"v{v}-{c['name']}") for c in CASES if "hex" in c
           for v in c["versions"]]  # fmt: skip
STREAMS = [c for c in CASES if "messages" in c]

pytestmark = pytest.mark.skipif(not VECTOR_FILES, reason="proto/vectors not found (repo only)")


def from_json(v: Any) -> Any:
    """A vector's JSON message -> wire value: ``{"$bin": hex}`` becomes bytes."""
    if isinstance(v, dict):
        if set(v) == {"$bin"}:
            return bytes.fromhex(v["$bin"])
        return {k: from_json(x) for k, x in v.items()}
    if isinstance(v, list):
        return [from_json(x) for x in v]
    return v


@pytest.mark.parametrize(("version", "case"), VALID)
def test_valid_vector(version: int, case: dict[str, Any]) -> None:
    canonical = bytes.fromhex(case["canonical_hex"])
    msg = decode(canonical, version=version)
    assert encode(msg) == canonical
    assert to_wire(msg) == from_json(case["message"])
    for alt in case["also_accept_hex"]:
        assert encode(decode(bytes.fromhex(alt), version=version)) == canonical, alt


@pytest.mark.parametrize(("version", "case"), INVALID)
def test_invalid_vector(version: int, case: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError) as info:
        decode(bytes.fromhex(case["hex"]), version=version)
    assert info.value.code == case["error"], info.value.message
    assert info.value.field == case.get("field")


@pytest.mark.parametrize("case", STREAMS, ids=lambda c: c["name"])
def test_stream_vector(case: dict[str, Any]) -> None:
    avatars: dict[int, AvatarState | None] = {a["handle"]: None for a in case["avatars"]}
    bones = {a["handle"]: skeleton2offsets(from_json(a["skeleton"])) for a in case["avatars"]}
    tol = case["tolerance"]
    for k, hexed in enumerate(case["messages"]):
        msg = decode(bytes.fromhex(hexed), version=2)
        assert isinstance(msg, Poses)
        if "error" in case and k == len(case["messages"]) - 1:
            with pytest.raises(ProtocolError) as info:
                decode_records(msg.data, avatars)
            assert (info.value.code, info.value.field) == (case["error"], case["field"])
            return
        got = decode_records(msg.data, avatars)
        want = case["expect"][k]
        assert [(r.avatar_id, r.state.seq, r.keyframe, r.reach_limited) for r in got] == [
            (w["handle"], w["seq"], w["keyframe"], w["reach_limited"]) for w in want
        ]
        for r, w in zip(got, want, strict=True):
            np.testing.assert_allclose(np.array(r.state.root) * ROOT_UNIT_M, w["root"], atol=tol)
            np.testing.assert_allclose(r.state.items, w["items"], atol=tol)
            np.testing.assert_allclose(
                r.state.positions(bones[r.avatar_id]), w["positions"], atol=tol
            )
    assert "error" not in case


def test_every_message_type_has_vectors() -> None:
    for version, types in ((1, V1_TYPES), (2, V2_TYPES)):
        valid = {c["message"]["type"] for c in CASES if "message" in c and version in c["versions"]}
        assert valid == types, version
    assert set(FIELDS) == V1_TYPES | V2_TYPES
    names = [c["name"] for c in CASES]
    assert len(names) == len(set(names))


def test_canonical_order_is_the_schema_order() -> None:
    """proto/fields.json lists the fields in canonical order; so does FIELDS."""
    schema = json.loads((PROTO / "fields.json").read_text("utf-8"))
    assert {k: tuple(f["name"] for f in v["fields"]) for k, v in schema["messages"].items()} == (
        FIELDS
    )
    for case in CASES:  # and the canonical bytes are plain packb of the message
        if "message" not in case:
            continue
        packed = msgpack.packb(from_json(case["message"]), use_bin_type=True)
        assert packed.hex() == case["canonical_hex"], case["name"]
