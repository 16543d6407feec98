"""Run proto/vectors/*.json against the codec, and check the vector files themselves.

Every valid case: the canonical bytes decode, re-encode to themselves and match the
case's ``message``; every ``also_accept_hex`` decodes to the same message. Every
invalid case fails with exactly its code (and field). The files must be what
``proto/vectors/generate.py`` writes, and ``proto/schema.json`` must describe the
same messages as the codec.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import msgpack
import pytest

from posecast.errors import ProtocolError
from posecast.online.protocol import decode, encode, to_wire
from posecast.online.protocol import messages as m
from posecast.online.protocol.wire import DECODERS, FIELD_ORDER

PROTO = Path(__file__).resolve().parents[3] / "proto"
VECTOR_FILES = sorted((PROTO / "vectors").glob("*.json"))
CASES = [(f.stem, c) for f in VECTOR_FILES for c in json.loads(f.read_text())]
VALID = [c for _, c in CASES if "message" in c]
INVALID = [c for _, c in CASES if "error" in c]


def from_json(v: Any) -> Any:
    """JSON message -> wire value: ``{"$bin": hex}`` becomes bytes."""
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


# --- the vector files themselves ----------------------------------------------------


def test_cases_have_the_documented_shape() -> None:
    names = [c["name"] for _, c in CASES]
    assert len(names) == len(set(names))
    codes = {row["code"] for row in json.loads((PROTO / "errors.json").read_text())}
    for _, case in CASES:
        if "message" in case:
            assert set(case) == {
                "name",
                "description",
                "message",
                "canonical_hex",
                "also_accept_hex",
            }
            hexes = [case["canonical_hex"], *case["also_accept_hex"]]
            assert len(set(hexes)) == len(hexes), case["name"]
        else:
            assert set(case) - {"field"} == {"name", "description", "hex", "error"}
            assert case["error"] in codes
            hexes = [case["hex"]]
        for h in hexes:
            assert h == bytes.fromhex(h).hex(), case["name"]  # lower-case, even length


def test_canonical_bytes_are_plain_msgpack_of_the_message() -> None:
    """The canonical rule is what the README says: packb of the map, in its order."""
    for case in VALID:
        packed = msgpack.packb(from_json(case["message"]), use_bin_type=True)
        assert packed.hex() == case["canonical_hex"], case["name"]


def test_every_type_and_decoder_code_is_covered() -> None:
    files = {name for name, _ in CASES}
    assert files == {*DECODERS, "envelope"}
    assert {c["message"]["type"] for c in VALID} == set(DECODERS)
    decoder_codes = {
        r["code"] for r in json.loads((PROTO / "errors.json").read_text()) if r["decoder"]
    }
    assert {c["error"] for c in INVALID} == decoder_codes


def _generator() -> ModuleType:
    path = PROTO / "vectors" / "generate.py"
    spec = importlib.util.spec_from_file_location("posecast_vector_generator", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_files_are_what_the_generator_writes() -> None:
    gen = _generator()
    files = gen.build()
    assert sorted(files) == [f.name for f in VECTOR_FILES]
    for name, cases in files.items():
        assert (PROTO / "vectors" / name).read_text() == gen.render(cases), name
    assert (PROTO / "errors.json").read_text() == gen.error_table(files)


# --- schema.json --------------------------------------------------------------------


SCHEMA = json.loads((PROTO / "schema.json").read_text())


def test_schema_lists_the_codec_messages_in_canonical_order() -> None:
    assert list(SCHEMA["messages"]) == list(FIELD_ORDER)
    for kind, spec in SCHEMA["messages"].items():
        assert tuple(f["name"] for f in spec["fields"]) == FIELD_ORDER[kind], kind
    for case in VALID:  # the canonical maps follow the same order
        keys = list(case["message"])
        assert keys[0] == "type"
        order = FIELD_ORDER[case["message"]["type"]]
        assert keys[1:] == [k for k in order if k in keys], case["name"]


def test_schema_roles_limits_and_constants_match() -> None:
    assert {r: frozenset(v) for r, v in SCHEMA["roles"].items()} == m.ROLE_MAY_SEND
    server = {k for k, v in SCHEMA["messages"].items() if v["from"] in ("server", "both")}
    client = {k for k, v in SCHEMA["messages"].items() if v["from"] in ("client", "both")}
    assert server == m.SERVER_SENDS
    assert client == set().union(*m.ROLE_MAY_SEND.values())
    limits = {k: (v["min"], v["max"]) for k, v in SCHEMA["limits"].items()}
    assert limits == m.LIMIT_RANGES
    assert [f["name"] for f in SCHEMA["types"]["limits"]["fields"]] == list(m.LIMIT_RANGES)
    c, s = SCHEMA["constants"], SCHEMA["structure"]
    assert (c["max_coord_m"], c["quat_tolerance"], c["max_time_s"]) == (
        m.MAX_COORD_M,
        m.QUAT_TOLERANCE,
        m.MAX_TIME_S,
    )
    assert (c["min_height_m"], c["max_height_m"]) == (m.MIN_HEIGHT_M, m.MAX_HEIGHT_M)
    assert (c["max_id_bytes"], c["max_lookahead_frames"]) == (
        m.MAX_ID_BYTES,
        m.MAX_LOOKAHEAD_FRAMES,
    )
    assert s == {
        "max_depth": m.MAX_DEPTH,
        "max_array_len": m.MAX_ARRAY_LEN,
        "max_map_len": m.MAX_MAP_LEN,
        "max_str_bytes": m.MAX_STR_BYTES,
        "max_bin_bytes": m.MAX_BIN_BYTES,
    }


def test_schema_required_fields_are_required() -> None:
    """Drop each required field from a valid vector: BAD_FIELD naming that field."""
    first = {}
    for case in VALID:
        first.setdefault(case["message"]["type"], from_json(case["message"]))
    for kind, spec in SCHEMA["messages"].items():
        wire = first[kind]
        for f in spec["fields"]:
            assert f["required"] is (f["name"] in wire) or not f["required"], (kind, f["name"])
            if not f["required"]:
                continue
            broken = {k: v for k, v in wire.items() if k != f["name"]}
            with pytest.raises(ProtocolError) as info:
                decode(msgpack.packb(broken, use_bin_type=True))
            assert (info.value.code, info.value.field) == ("BAD_FIELD", f["name"]), kind
