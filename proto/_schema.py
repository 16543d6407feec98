"""``schema.json``: the JSON Schema (draft 2020-12) of every message, built from ``fields.json``.

Used by ``generate_spec.py``. ``fields.json`` names each field's type and bounds; this
module turns them into JSON Schema keywords, and adds the rules that tie fields together
(``calibrate``'s two forms, ``frame``'s rows and ``valid`` bits, what a ``selector`` kind
or a v2 ``presence`` join asks for), each written out below where ``fields.json`` only
names it (``one_of``, ``by``, ``kinds``, ``required_for``).

The schema validates a message as the JSON data model renders it (README.md, "The JSON
data model"): bins are ``{"$bin": hex}``, non-finite floats ``{"$float": "NaN"}``. It
holds for the **default limits** (a server may lower them) and checks what a schema
can: types, shapes, enums, ranges, and string lengths counted in code points (exact for
the ASCII-only ids, rooms, codes and layouts; for names, text and tokens it is the
byte bound read as a code-point bound, which every string within the byte bound meets).
"""

from __future__ import annotations

import re
from typing import Any

Schema = dict[str, Any]

DRAFT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_ID = "urn:posecast:proto:schema"


def ref(name: str) -> Schema:
    return {"$ref": f"#/$defs/{name}"}


def has(field: str) -> Schema:
    """Present and not nil (nil means absent)."""
    return {"required": [field], "properties": {field: {"not": {"type": "null"}}}}


def nullable(s: Schema) -> Schema:
    return {"anyOf": [{"type": "null"}, s]}


class Builder:
    """The schema of one ``fields.json``."""

    def __init__(self, fields: dict[str, Any]) -> None:
        self.f = fields
        self.types: dict[str, Any] = fields["types"]
        self.limits = {k: v["max"] for k, v in fields["limits"].items()}  # the defaults
        self.structure = fields["structure"]
        self.max_coord = fields["constants"]["max_coord_m"]
        self.max_quat = 1.0 + fields["constants"]["quat_tolerance"]

    # --- the data model: bounded values, bins, non-finite floats --------------------------

    def max_bin(self, version: int) -> int:
        if version >= 2:
            return int(self.f["structure_v2"]["max_bin_bytes"])
        return int(self.structure["max_bin_bytes"])

    def data_model_defs(self) -> Schema:
        hexes = {"type": "string", "pattern": "^(?:[0-9a-f]{2})*$"}
        out: Schema = {
            "bin": {
                "$comment": 'a msgpack bin: {"$bin": its bytes in lower-case hex}',
                "type": "object",
                "properties": {"$bin": hexes},
                "required": ["$bin"],
                "additionalProperties": False,
            },
            "nonfinite": {
                "$comment": "a msgpack float that JSON has no number for",
                "type": "object",
                "properties": {"$float": {"enum": ["NaN", "Infinity", "-Infinity"]}},
                "required": ["$float"],
                "additionalProperties": False,
            },
            "any_number": {"anyOf": [{"type": "number"}, ref("nonfinite")]},
            "reserved": {
                "$comment": "the shape of a bin's or a float's rendering, which no map has",
                "type": "object",
                "maxProperties": 1,
                "anyOf": [
                    {"required": ["$bin"], "properties": {"$bin": True}},
                    {"required": ["$float"], "properties": {"$float": True}},
                ],
            },
        }
        depth = int(self.structure["max_depth"])
        for v in self.f["versions"]:
            out[f"v{v}.scalar"] = {
                "anyOf": [
                    {"type": ["null", "boolean", "number"]},
                    {"type": "string", "maxLength": self.structure["max_str_bytes"]},
                    ref("nonfinite"),
                    self.bin_of(v, max_bytes=self.max_bin(v)),
                ]
            }
            for d in range(2, depth + 2):
                if d > depth:
                    out[f"v{v}.value_d{d}"] = ref(f"v{v}.scalar")
                    continue
                inner = ref(f"v{v}.value_d{d + 1}")
                out[f"v{v}.value_d{d}"] = {
                    "anyOf": [
                        ref(f"v{v}.scalar"),
                        {
                            "type": "array",
                            "maxItems": self.structure["max_array_len"],
                            "items": inner,
                        },
                        {
                            "type": "object",
                            "maxProperties": self.structure["max_map_len"],
                            "additionalProperties": inner,
                            "not": ref("reserved"),
                        },
                    ]
                }
        out["v1.value_d2"]["$comment"] = (
            "any value at depth 2 (a field of the root map) within the structural bounds;"
            " containers nest to depth 8, the root map being depth 1"
        )
        return out

    def bin_of(
        self, version: int, *, size: int | None = None, max_bytes: int | None = None
    ) -> Schema:
        hexes: Schema = {"type": "string", "pattern": "^(?:[0-9a-f]{2})*$"}
        if size is not None:
            hexes["minLength"] = hexes["maxLength"] = 2 * size
        else:
            hexes["maxLength"] = 2 * (max_bytes if max_bytes is not None else self.max_bin(version))
        return {
            "type": "object",
            "properties": {"$bin": hexes},
            "required": ["$bin"],
            "additionalProperties": False,
        }

    # --- one field ------------------------------------------------------------------------

    def bound(self, value: Any) -> Any:
        """A bound of fields.json: a number, or a limit's name (its default)."""
        return self.limits[value] if isinstance(value, str) else value

    def resolve(self, fdef: dict[str, Any]) -> dict[str, Any]:
        named = self.types.get(fdef["type"])
        if named is None:
            return dict(fdef)
        return {**self.resolve(named), **fdef, "type": self.resolve(named)["type"]}

    def value(self, fdef: dict[str, Any], version: int, depth: int) -> Schema:
        """The schema of a present, non-nil value of ``fdef`` at nesting ``depth``."""
        name = fdef["type"]
        if name == "layout":
            return self.layout()
        if name in ("tracker", "trackers", "sites"):
            return self.rows(name, strict=False)
        f = self.resolve(fdef)
        kind = f["type"]
        out: Schema
        if "const_by_version" in f:
            return {"type": "integer", "const": f["const_by_version"][str(version)]}
        if kind == "int":
            out = {"type": "integer"}
            if f.get("range") == "limits":
                lim = self.f["limits"][f["name"]]
                out |= {"minimum": lim["min"], "maximum": lim["max"]}
        elif kind == "float":
            out = {"type": "number"}
        elif kind == "bool":
            out = {"type": "boolean"}
        elif kind == "str":
            out = {"type": "string"}
        elif kind == "bin":
            if "bytes" in f:
                return self.bin_of(version, size=f["bytes"])
            return self.bin_of(version, max_bytes=f.get("max_bytes"))
        elif kind == "array":
            out = {"type": "array", "items": self.value(f["items"], version, depth + 1)}
            if "len" in f:
                out |= {"minItems": f["len"], "maxItems": f["len"]}
            if "min_len" in f:
                out["minItems"] = f["min_len"]
            if "max_len" in f:
                out["maxItems"] = self.bound(f["max_len"])
            return out
        elif kind == "map":
            return self.object(f["fields"], version, depth)
        else:
            raise ValueError(f"unknown field type {kind!r}")
        if "min" in f:
            out["minimum"] = self.bound(f["min"])
        if "max" in f:
            out["maximum"] = self.bound(f["max"])
        if "min_bytes" in f:
            out["minLength"] = self.bound(f["min_bytes"])
        if "max_bytes" in f:
            out["maxLength"] = self.bound(f["max_bytes"])
        if "enum" in f:
            out["enum"] = f["enum"]
        if "const" in f:
            out["const"] = f["const"]
        if "max_with_sites" in f:  # frame.valid: its bound with trackers is a rule (frame_rules)
            out["maximum"] = f["max_with_sites"]
        if "pattern" in f:
            out |= pattern(f["pattern"])
        return out

    def object(self, fields: list[dict[str, Any]], version: int, depth: int) -> Schema:
        """A nested map (``members[]``, ``limits``): its fields of ``version``; others are
        unknown fields, held to the structural bounds one level down."""
        props: Schema = {}
        required = []
        for fd in fields:
            if version not in fd.get("versions", [version]):
                continue
            v = self.value(fd, version, depth + 1)
            if fd.get("required"):
                required.append(fd["name"])
                props[fd["name"]] = v
            else:
                props[fd["name"]] = nullable(v)
        return {
            "type": "object",
            "maxProperties": self.structure["max_map_len"],
            "required": required,
            "properties": props,
            "additionalProperties": ref(f"v{version}.value_d{depth + 1}"),
        }

    def layout(self) -> Schema:
        t = self.types["layout"]
        ts = t["tracker_set"]
        site = "(?:" + "|".join(ts["sites"]) + ")"
        entry = site + "(?:" + re.escape(ts["inertial_suffix"]) + ")?"
        needs = "".join(f"(?=(?:.*,)?{s}(?:,|$))" for s in ts["required"])
        twice = r"(?!(?:.*,)?([a-z_]+)(?::imu)?,(?:.*,)?\1(?::imu)?(?:,|$))"
        return {
            "type": "string",
            "minLength": t["min_bytes"],
            "maxLength": t["max_bytes"],
            "anyOf": [
                {"enum": t["named"]},
                {
                    "$comment": "a tracker set: known sites, each once, head and hands positional",
                    "pattern": f"^{needs}{twice}{entry}(?:,{entry})*$",
                    "not": {"pattern": "[^a-z_:,]"},
                },
            ],
        }

    def rows(self, name: str, *, strict: bool) -> Schema:
        """``tracker`` rows: any numbers (NaN too: an untracked row is only type-checked),
        or, ``strict``, a tracked row's bounds: the first three within +-max_coord_m, the
        quaternion's components within 1 + tolerance (its norm is not a schema's to
        check)."""
        row: Schema
        if strict:
            pos = {"type": "number", "minimum": -self.max_coord, "maximum": self.max_coord}
            quat = {"type": "number", "minimum": -self.max_quat, "maximum": self.max_quat}
            row = {"type": "array", "prefixItems": [pos] * 3 + [quat] * 4}
        else:
            row = {"type": "array", "minItems": 7, "maxItems": 7, "items": ref("any_number")}
        if name == "tracker":
            return row
        t = self.types[name]
        out: Schema = {"type": "array", "items": row}
        if "len" in t:
            out |= {"minItems": t["len"], "maxItems": t["len"]}
        if "min_len" in t:
            out |= {"minItems": t["min_len"], "maxItems": t["max_len"]}
        return out

    # --- one message ------------------------------------------------------------------------

    def message(self, kind: str, version: int) -> Schema:
        spec = self.f["messages"][kind]
        fields = [f for f in spec["fields"] if version in f.get("versions", [version])]
        conditional = {f["name"] for f in fields if "required_for" in f and "kinds" not in f}
        if kind in ("frame", "calibrate"):
            conditional |= {"trackers", "sites"}
        props: Schema = {"type": {"const": kind}}
        required = ["type"]
        for fd in fields:
            if fd["name"] in conditional:
                continue  # typed where it applies, below; elsewhere an unknown field
            v = self.value(fd, version, 2)
            if fd.get("required"):
                required.append(fd["name"])
                props[fd["name"]] = v
            else:
                props[fd["name"]] = nullable(v)
        out: Schema = {
            "type": "object",
            "maxProperties": self.structure["max_map_len"],
            "required": required,
            "properties": props,
            "additionalProperties": ref(f"v{version}.value_d2"),
        }
        rules = self.rules(kind, spec, fields, version)
        if rules:
            out["allOf"] = rules
        return out

    def rules(self, kind: str, spec: Schema, fields: list[Schema], version: int) -> list[Schema]:
        if kind == "frame":
            return self.frame_rules()
        if kind == "calibrate":
            return self.calibrate_rules()
        if "by" not in spec:
            return []
        by = spec["by"]
        values = next(self.resolve(f) for f in fields if f["name"] == by)["enum"]
        out = []
        for k in values:
            then: Schema = {"allOf": []}
            props: Schema = {}
            for fd in fields:
                applies = k in fd.get("kinds", fd.get("required_for", [k]))
                if "kinds" not in fd and "required_for" not in fd:
                    continue
                if not applies and "kinds" in fd:
                    props[fd["name"]] = {"type": "null"}  # refused where it does not apply
                elif applies and "kinds" not in fd:
                    props[fd["name"]] = nullable(self.value(fd, version, 2))
                if k in fd.get("required_for", []):
                    then["allOf"].append(has(fd["name"]))
            if props:
                then["properties"] = props
            if not then["allOf"]:
                del then["allOf"]
            if len(then) > 0:
                out.append(
                    {"if": {"required": [by], "properties": {by: {"const": k}}}, "then": then}
                )
        return out

    def frame_rules(self) -> list[Schema]:
        """A frame has ``trackers`` or ``sites``, not both; ``valid`` is at most 15 with
        trackers and ``2^n - 1`` with ``n`` sites; a tracked row is within bounds (every
        row when ``valid`` is absent; with ``trackers``, the rows ``valid`` has a bit set
        for; with ``sites`` and a ``valid``, not checked here: bit tests on up to 10 rows
        are beyond a schema of reasonable size)."""
        both = {"allOf": [has("trackers"), has("sites")]}
        no_valid = {"properties": {"valid": {"type": "null"}}}
        rules: list[Schema] = [
            {"anyOf": [has("trackers"), has("sites")]},
            {"not": both},
            {
                "if": {"not": has("sites")},
                "then": {
                    "properties": {
                        "trackers": nullable(self.rows("trackers", strict=False)),
                        "valid": {"maximum": 15},
                    }
                },
                "else": {"properties": {"sites": self.rows("sites", strict=False)}},
            },
            {
                "if": no_valid,
                "then": {"properties": {"sites": {"items": self.rows("tracker", strict=True)}}},
            },
        ]
        strict = self.rows("tracker", strict=True)
        for slot in range(4):
            bit = [v for v in range(16) if v >> slot & 1]
            rules.append(
                {
                    "if": {"properties": {"valid": {"anyOf": [{"type": "null"}, {"enum": bit}]}}},
                    "then": {"properties": {"trackers": {"prefixItems": [True] * slot + [strict]}}},
                }
            )
        for n in range(1, self.types["sites"]["max_len"] + 1):
            rules.append(
                {
                    "if": {
                        "required": ["sites"],
                        "properties": {"sites": {"type": "array", "minItems": n, "maxItems": n}},
                    },
                    "then": {"properties": {"valid": {"maximum": 2**n - 1}}},
                }
            )
        return rules

    def calibrate_rules(self) -> list[Schema]:
        """Exactly one of ``height_m`` and ``tpose``; a T-pose has ``trackers`` or
        ``sites`` (not both), every row tracked. With ``height_m`` the rows are not read."""
        every = {"type": "array", "items": self.rows("tracker", strict=True)}
        return [
            {"anyOf": [has("height_m"), has("tpose")]},
            {"not": {"allOf": [has("height_m"), has("tpose")]}},
            {
                "if": has("tpose"),
                "then": {
                    "anyOf": [has("trackers"), has("sites")],
                    "not": {"allOf": [has("trackers"), has("sites")]},
                    "properties": {
                        "trackers": nullable(
                            {"allOf": [self.rows("trackers", strict=False), every]}
                        ),
                        "sites": nullable({"allOf": [self.rows("sites", strict=False), every]}),
                    },
                },
            },
        ]

    # --- the whole schema ---------------------------------------------------------------------

    def schema(self) -> Schema:
        defs = self.data_model_defs()
        roots = []
        for v in self.f["versions"]:
            kinds = [k for k, m in self.f["messages"].items() if v in m["versions"]]
            for k in kinds:
                defs[f"v{v}.{k}"] = self.message(k, v)
            defs[f"v{v}"] = {
                "$comment": f"a message of protocol v{v} ({self.f['subprotocols'][str(v)]})",
                "type": "object",
                "required": ["type"],
                "properties": {"type": {"type": "string", "enum": kinds}},
                "allOf": [
                    {
                        "if": {"required": ["type"], "properties": {"type": {"const": k}}},
                        "then": ref(f"v{v}.{k}"),
                    }
                    for k in kinds
                ],
            }
            roots.append(ref(f"v{v}"))
        return {
            "$schema": DRAFT,
            "$id": SCHEMA_ID,
            "$comment": (
                "posecast wire messages, v1 and v2, as the JSON data model renders them"
                " (README.md, 'schema.json'). Written by proto/generate_spec.py from"
                " fields.json: do not edit. Validate against #/$defs/v1 or #/$defs/v2,"
                " the connection's version; the root accepts a message of either."
            ),
            "anyOf": roots,
            "$defs": defs,
        }


def pattern(p: str) -> Schema:
    """A fields.json pattern (``^[class]+$``, or the error code's) as keywords that mean the
    same in ECMA-262 and in Python's ``re`` (whose ``$`` also matches before a final
    newline): a character class becomes "no character outside it"."""
    m = re.fullmatch(r"\^\[(\^?)(.*)\]\+\$", p)
    if m:
        negated, chars = m.groups()
        return {"not": {"pattern": f"[{'' if negated else '^'}{chars}]"}}
    if p == "^[A-Z][A-Z0-9_]{0,31}$":
        return {"pattern": "^[A-Z]", "not": {"pattern": "[^A-Z0-9_]"}, "maxLength": 32}
    raise ValueError(f"no portable form for the pattern {p!r}")
