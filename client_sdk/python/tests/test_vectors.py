"""Run every case of ``proto/vectors/*.json`` against the SDK's own codec.

Valid cases: the canonical bytes decode, re-encode to themselves byte for byte and
match the case's ``message``; every ``also_accept_hex`` decodes and re-encodes to
the canonical bytes. Invalid cases fail with exactly their code (and field).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgpack
import pytest

from posecast_client.codec import FIELDS, decode, encode, to_wire
from posecast_client.errors import ProtocolError

PROTO = Path(__file__).resolve().parents[3] / "proto"
VECTOR_FILES = sorted((PROTO / "vectors").glob("*.json"))
CASES = [c for f in VECTOR_FILES for c in json.loads(f.read_text("utf-8"))]
VALID = [c for c in CASES if "message" in c]
INVALID = [c for c in CASES if "error" in c]

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


@pytest.mark.parametrize("case", VALID, ids=lambda c: c["name"])
def test_valid_vector(case: dict[str, Any]) -> None:
    canonical = bytes.fromhex(case["canonical_hex"])
    msg = decode(canonical)
    assert encode(msg) == canonical
    assert to_wire(msg) == from_json(case["message"])
    for alt in case["also_accept_hex"]:
        assert encode(decode(bytes.fromhex(alt))) == canonical, alt


@pytest.mark.parametrize("case", INVALID, ids=lambda c: c["name"])
def test_invalid_vector(case: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError) as info:
        decode(bytes.fromhex(case["hex"]))
    assert info.value.code == case["error"], info.value.message
    assert info.value.field == case.get("field")


def test_every_message_type_has_vectors() -> None:
    assert {c["message"]["type"] for c in VALID} == set(FIELDS)
    names = [c["name"] for c in CASES]
    assert len(names) == len(set(names))


def test_canonical_order_is_the_schema_order() -> None:
    """proto/schema.json lists the fields in canonical order; so does FIELDS."""
    schema = json.loads((PROTO / "schema.json").read_text("utf-8"))
    assert {k: tuple(f["name"] for f in v["fields"]) for k, v in schema["messages"].items()} == (
        FIELDS
    )
    for case in VALID:  # and the canonical bytes are plain packb of the message
        packed = msgpack.packb(from_json(case["message"]), use_bin_type=True)
        assert packed.hex() == case["canonical_hex"], case["name"]
