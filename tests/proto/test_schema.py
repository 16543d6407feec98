"""``proto/schema.json`` against every message in ``proto/vectors``, with Python's
``jsonschema`` (the TypeScript SDK's ``test/schema.test.ts`` does the same with ajv).

* schema.json is a valid draft 2020-12 schema (the meta-schema check);
* every valid case, canonical bytes and every ``also_accept_hex``, rendered by the
  JSON data model (``proto/datamodel.py``), passes in every version it lists, and its
  canonical rendering is the case's ``message``; so does every message of a stream;
* every invalid case fails in every version it lists, except those
  ``proto/schema_gaps.json`` names, which pass (or, ``no_rendering``, have no
  rendering): the list is exactly what the schema cannot tell.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from jsonschema import Draft202012Validator
from referencing import Registry, Resource

from tests.proto.helpers import PROTO, cases, load

datamodel = load("datamodel")
SCHEMA = json.loads((PROTO / "schema.json").read_text("utf-8"))
GAPS = json.loads((PROTO / "schema_gaps.json").read_text("utf-8"))
REGISTRY = Registry().with_resource(SCHEMA["$id"], Resource.from_contents(SCHEMA))
VALIDATORS = {
    v: Draft202012Validator({"$ref": f"{SCHEMA['$id']}#/$defs/v{v}"}, registry=REGISTRY)
    for v in (1, 2)
}
CASES = cases()
VALID = [(v, c) for c in CASES if "message" in c for v in c["versions"]]
STREAMS = [(v, c) for c in CASES if "messages" in c for v in c["versions"]]
INVALID = [(v, c) for c in CASES if "hex" in c for v in c["versions"]]


def _params(pairs: list[tuple[int, dict[str, Any]]]) -> list[Any]:
    return [pytest.param(v, c, id=f"v{v}-{c['name']}") for v, c in pairs]


def _errors(version: int, message: Any) -> list[str]:
    return [
        f"{'/'.join(map(str, e.absolute_path))}: {e.message[:200]}"
        for e in VALIDATORS[version].iter_errors(message)
    ]


def test_schema_is_draft_2020_12() -> None:
    assert SCHEMA["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    Draft202012Validator.check_schema(SCHEMA)


@pytest.mark.parametrize(("version", "case"), _params(VALID))
def test_valid_vector_passes(version: int, case: dict[str, Any]) -> None:
    assert datamodel.render(bytes.fromhex(case["canonical_hex"])) == case["message"]
    for h in (case["canonical_hex"], *case["also_accept_hex"]):
        assert _errors(version, datamodel.render(bytes.fromhex(h))) == [], h


@pytest.mark.parametrize(("version", "case"), _params(STREAMS))
def test_stream_messages_pass(version: int, case: dict[str, Any]) -> None:
    """A stream's records may be wrong (its ``error``), but every message is a ``poses``."""
    for h in case["messages"]:
        assert _errors(version, datamodel.render(bytes.fromhex(h))) == [], h


@pytest.mark.parametrize(("version", "case"), _params(INVALID))
def test_invalid_vector_fails_unless_listed(version: int, case: dict[str, Any]) -> None:
    gap = GAPS["vectors"].get(case["name"], {})
    reason = gap.get("reason") if version in gap.get("versions", []) else None
    try:
        message = datamodel.render(bytes.fromhex(case["hex"]))
    except datamodel.NotRepresentableError:
        assert reason == "no_rendering", f"{case['name']}: no rendering, so list it so"
        return
    errors = _errors(version, message)
    if reason is None:
        assert errors, f"{case['name']} ({case['error']}) passes the schema in v{version}"
    else:
        assert reason != "no_rendering", f"{case['name']} has a rendering"
        assert not errors, f"{case['name']} is listed for v{version} but fails: {errors}"


def test_gaps_name_invalid_vectors_and_known_reasons() -> None:
    invalid = {c["name"]: c for c in CASES if "hex" in c}
    for name, gap in GAPS["vectors"].items():
        assert set(gap["versions"]) <= set(invalid[name]["versions"]), name
        assert gap["reason"] in GAPS["reasons"], name
    assert {g["reason"] for g in GAPS["vectors"].values()} == set(GAPS["reasons"])


def test_nonfinite_floats_and_bins_render_as_the_readme_says() -> None:
    render = datamodel.render
    assert render(bytes.fromhex("81a178cb7ff8000000000000")) == {"x": {"$float": "NaN"}}
    assert render(bytes.fromhex("81a178cbfff0000000000000")) == {"x": {"$float": "-Infinity"}}
    assert render(bytes.fromhex("81a178c40201ff")) == {"x": {"$bin": "01ff"}}
    for bad in ("81a17881a42462696e01", "82a17801a17802"):  # {"$bin": 1}; a key twice
        with pytest.raises(datamodel.NotRepresentableError):
            render(bytes.fromhex(bad))
