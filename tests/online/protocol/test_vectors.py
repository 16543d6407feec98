"""Run proto/vectors/*.json against the codec, and check the vector files themselves.

Every valid case, in every protocol version it lists: the canonical bytes decode,
re-encode to themselves and match the case's ``message``; every ``also_accept_hex``
decodes to the same message. Every invalid case fails with exactly its code (and
field). Every stream case decodes message by message with the reference record
decoder to its ``expect``. The files must be what ``proto/vectors/generate.py``
writes, and ``proto/fields.json`` must describe the same messages as the codec.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import msgpack
import numpy as np
import pytest

from posecast.body import forecast as body_forecast
from posecast.errors import ProtocolError
from posecast.online.protocol import decode, encode, records, to_wire
from posecast.online.protocol import messages as m
from posecast.online.protocol.wire import DECODERS, FIELD_ORDER

PROTO = Path(__file__).resolve().parents[3] / "proto"
VECTOR_FILES = sorted((PROTO / "vectors").glob("*.json"))
CASES = [(f.stem, c) for f in VECTOR_FILES for c in json.loads(f.read_text())]
STREAMS = [c for _, c in CASES if "messages" in c]
VALID = [(v, c) for _, c in CASES if "message" in c for v in c["versions"]]
INVALID = [(v, c) for _, c in CASES if "hex" in c for v in c["versions"]]


def _params(cases: list[tuple[int, dict[str, Any]]]) -> list[Any]:
    return [pytest.param(v, c, id=f"v{v}-{c['name']}") for v, c in cases]


def from_json(v: Any) -> Any:
    """JSON message -> wire value: ``{"$bin": hex}`` becomes bytes."""
    if isinstance(v, dict):
        if set(v) == {"$bin"}:
            return bytes.fromhex(v["$bin"])
        return {k: from_json(x) for k, x in v.items()}
    if isinstance(v, list):
        return [from_json(x) for x in v]
    return v


@pytest.mark.parametrize(("version", "case"), _params(VALID))
def test_valid_vector(version: int, case: dict[str, Any]) -> None:
    canonical = bytes.fromhex(case["canonical_hex"])
    msg = decode(canonical, version=version)
    assert encode(msg) == canonical
    assert to_wire(msg) == from_json(case["message"])
    for alt in case["also_accept_hex"]:
        assert encode(decode(bytes.fromhex(alt), version=version)) == canonical, alt


@pytest.mark.parametrize(("version", "case"), _params(INVALID))
def test_invalid_vector(version: int, case: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError) as info:
        decode(bytes.fromhex(case["hex"]), version=version)
    assert info.value.code == case["error"], info.value.message
    assert info.value.field == case.get("field")


@pytest.mark.parametrize("case", STREAMS, ids=lambda c: c["name"])
def test_stream_vector(case: dict[str, Any]) -> None:
    """The reference record decoder (the server's own) reproduces every stream."""
    refs: dict[int, records.Recon | None] = {a["handle"]: None for a in case["avatars"]}
    bones = {a["handle"]: records.bytes2skeleton(from_json(a["skeleton"])) for a in case["avatars"]}
    tol = case["tolerance"]
    for k, hexed in enumerate(case["messages"]):
        msg = decode(bytes.fromhex(hexed), version=2)
        assert isinstance(msg, m.Poses)
        if "error" in case and k == len(case["messages"]) - 1:
            with pytest.raises(ProtocolError) as info:
                records.decode_records(msg.data, refs)
            assert (info.value.code, info.value.field) == (case["error"], case["field"])
            return
        got = records.decode_records(msg.data, refs)
        want = case["expect"][k]
        assert [r.avatar_id for r in got] == [w["handle"] for w in want]
        for r, w in zip(got, want, strict=True):
            assert (r.recon.seq, r.keyframe, r.reach_limited) == (
                w["seq"], w["keyframe"], w["reach_limited"]
            )  # fmt: skip
            np.testing.assert_allclose(
                np.asarray(r.recon.root) * records.ROOT_UNIT_M, w["root"], atol=tol
            )
            np.testing.assert_allclose(r.recon.items, w["items"], atol=tol)
            np.testing.assert_allclose(
                r.recon.positions(bones[r.avatar_id]), w["positions"], atol=tol
            )
    assert "error" not in case


# --- the vector files themselves ----------------------------------------------------


def test_cases_have_the_documented_shape() -> None:
    names = [c["name"] for _, c in CASES]
    assert len(names) == len(set(names))
    codes = {row["code"] for row in json.loads((PROTO / "errors.json").read_text())}
    for _, case in CASES:
        assert case["versions"] and set(case["versions"]) <= set(m.VERSIONS), case["name"]
        if "message" in case:
            assert set(case) == {
                "name",
                "description",
                "versions",
                "message",
                "canonical_hex",
                "also_accept_hex",
            }
            hexes = [case["canonical_hex"], *case["also_accept_hex"]]
            assert len(set(hexes)) == len(hexes), case["name"]
        elif "messages" in case:
            keys = {"name", "description", "versions", "avatars", "messages", "expect",
                    "tolerance"}  # fmt: skip
            assert set(case) - {"error", "field"} == keys, case["name"]
            assert len(case["expect"]) == len(case["messages"]) - ("error" in case)
            assert case.get("error", "BAD_FIELD") in codes
            hexes = case["messages"]
        else:
            assert set(case) - {"field"} == {"name", "description", "versions", "hex", "error"}
            assert case["error"] in codes
            hexes = [case["hex"]]
        for h in hexes:
            assert h == bytes.fromhex(h).hex(), case["name"]  # lower-case, even length


def test_canonical_bytes_are_plain_msgpack_of_the_message() -> None:
    """The canonical rule is what the README says: packb of the map, in its order."""
    for _, case in VALID:
        packed = msgpack.packb(from_json(case["message"]), use_bin_type=True)
        assert packed.hex() == case["canonical_hex"], case["name"]


def test_every_type_and_decoder_code_is_covered() -> None:
    files = {name for name, _ in CASES}
    assert files == {*DECODERS[1], *DECODERS[2], "envelope"}
    for version in m.VERSIONS:
        assert {c["message"]["type"] for v, c in VALID if v == version} == set(DECODERS[version])
    decoder_codes = {
        r["code"] for r in json.loads((PROTO / "errors.json").read_text()) if r["decoder"]
    }
    assert {c["error"] for _, c in INVALID} == decoder_codes
    assert {c["error"] for c in STREAMS if "error" in c} <= decoder_codes


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


# --- fields.json --------------------------------------------------------------------


SCHEMA = json.loads((PROTO / "fields.json").read_text())


def test_schema_lists_the_codec_messages_in_canonical_order() -> None:
    assert list(SCHEMA["messages"]) == list(FIELD_ORDER)
    for kind, spec in SCHEMA["messages"].items():
        assert tuple(f["name"] for f in spec["fields"]) == FIELD_ORDER[kind], kind
    for _, case in VALID:  # the canonical maps follow the same order
        keys = list(case["message"])
        assert keys[0] == "type"
        order = FIELD_ORDER[case["message"]["type"]]
        assert keys[1:] == [k for k in order if k in keys], case["name"]


def test_schema_roles_limits_and_constants_match() -> None:
    assert {r: frozenset(v) for r, v in SCHEMA["roles"].items()} == m.ROLE_MAY_SEND
    assert {r: frozenset(v) for r, v in SCHEMA["roles_v2"].items()} == m.ROLE_MAY_SEND_V2
    for version, sends, roles in ((1, m.SERVER_SENDS, m.ROLE_MAY_SEND),
                                  (2, m.SERVER_SENDS_V2, m.ROLE_MAY_SEND_V2)):  # fmt: skip
        msgs = {k: v for k, v in SCHEMA["messages"].items() if version in v["versions"]}
        assert set(msgs) == set(DECODERS[version]), version
        server = {k for k, v in msgs.items() if v["from"] in ("server", "both")}
        client = {k for k, v in msgs.items() if v["from"] in ("client", "both")}
        assert server == sends
        assert client == set().union(*roles.values())
    c2, s2 = SCHEMA["constants_v2"], SCHEMA["structure_v2"]
    assert (c2["root_unit_m"], c2["skeleton_unit_m"], c2["skeleton_bytes"]) == (
        records.ROOT_UNIT_M, records.SKELETON_UNIT_M, records.SKELETON_BYTES
    )  # fmt: skip
    assert (c2["smallest3_scale"], c2["rot_step_rad"], c2["keyframe_bytes"]) == (
        records.SMALLEST3_SCALE, records.ROT_STEP_RAD, records.KEYFRAME_BYTES
    )  # fmt: skip
    assert tuple(c2["rot_widths"]) == records.ROT_WIDTHS
    assert tuple(c2["root_widths"]) == records.ROOT_WIDTHS
    assert tuple(c2["pose_rates_hz"]) == m.POSE_RATES_HZ
    assert c2["max_forecast_ms"] == m.MAX_FORECAST_MS == body_forecast.MAX_FORECAST_MS
    assert s2 == {"max_server_message_bytes": m.MAX_SERVER_MESSAGE_BYTES_V2,
                  "max_bin_bytes": m.MAX_BIN_BYTES_V2}  # fmt: skip
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
    for version in m.VERSIONS:
        first = {}
        for v, case in VALID:
            if v == version:
                first.setdefault(case["message"]["type"], from_json(case["message"]))
        for kind, spec in SCHEMA["messages"].items():
            if version not in spec["versions"]:
                continue
            wire = first[kind]
            for f in spec["fields"]:
                required = f["required"] and version in f.get("versions", m.VERSIONS)
                if not required:
                    continue
                assert f["name"] in wire, (version, kind, f["name"])
                broken = {k: v for k, v in wire.items() if k != f["name"]}
                with pytest.raises(ProtocolError) as info:
                    decode(msgpack.packb(broken, use_bin_type=True), version=version)
                assert (info.value.code, info.value.field) == ("BAD_FIELD", f["name"]), kind
