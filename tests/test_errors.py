"""The wire error codes agree everywhere: errors.py, proto/errors.json, proto/README.md."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from posecast.errors import PosecastError, ProtocolError
from posecast.online.protocol import Error

PROTO = Path(__file__).resolve().parents[1] / "proto"
CLASSES = ProtocolError.__subclasses__()


def _json_rows() -> list[dict[str, object]]:
    rows: list[dict[str, object]] = json.loads((PROTO / "errors.json").read_text())
    return rows


def test_errors_json_matches_the_classes() -> None:
    rows = _json_rows()
    assert [r["code"] for r in rows] == [c.code for c in CLASSES]
    for row, cls in zip(rows, CLASSES, strict=True):
        assert row["fatal"] is cls.fatal, cls.code
        assert row["meaning"] == " ".join((cls.__doc__ or "").replace("``", "").split())
        assert set(row) == {"code", "fatal", "decoder", "meaning"}


def test_codes_are_unique_and_class_names_follow_them() -> None:
    codes = [c.code for c in CLASSES]
    assert len(codes) == len(set(codes))
    for cls in CLASSES:
        assert re.fullmatch(r"[A-Z][A-Z0-9_]{0,31}", cls.code)
        camel = "".join(part.capitalize() for part in cls.code.split("_"))
        assert cls.__name__ == camel + "Error"
        assert issubclass(cls, PosecastError)


def test_readme_lists_every_code_once() -> None:
    text = (PROTO / "README.md").read_text()
    section = text.split("## Error codes", 1)[1].split("\n## ", 1)[0]
    listed = re.findall(r"^\* `([A-Z_]+)`", section, flags=re.MULTILINE)
    assert sorted(listed) == sorted(c.code for c in CLASSES)
    assert len(listed) == len(set(listed))
    for line in section.splitlines():
        m = re.match(r"^\* `([A-Z_]+)`", line)
        if m:  # the (fatal) marker matches the class default
            assert ("(fatal)" in line) is ProtocolError.for_code(m.group(1)).fatal, line


def test_readme_decoder_section_matches_errors_json() -> None:
    text = (PROTO / "README.md").read_text()
    section = text.split("### Decoder errors", 1)[1].split("### Server errors", 1)[0]
    listed = set(re.findall(r"^\* `([A-Z_]+)`", section, flags=re.MULTILINE))
    assert listed == {r["code"] for r in _json_rows() if r["decoder"]}


def test_the_docstring_tree_draws_every_class() -> None:
    import posecast.errors as errors

    tree = errors.__doc__ or ""
    for cls in CLASSES:
        assert re.search(rf"{cls.__name__}\s+{cls.code}\b", tree), cls.__name__


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.code)
def test_for_code_and_wire_round_trip(cls: type[ProtocolError]) -> None:
    assert ProtocolError.for_code(cls.code) is cls
    exc = cls("detail", field="trackers[1]", ref_seq=41)
    wire = Error.from_exception(exc)
    assert (wire.code, wire.message, wire.fatal, wire.field, wire.ref_seq) == (
        cls.code,
        "detail",
        cls.fatal,
        "trackers[1]",
        41,
    )
    back = wire.to_exception()
    assert type(back) is cls and back.field == "trackers[1]" and back.ref_seq == 41


def test_fatal_can_be_overridden_per_raise() -> None:
    assert ProtocolError.for_code("FORBIDDEN")("x", fatal=True).fatal is True
    assert ProtocolError.for_code("FORBIDDEN").fatal is False


def test_an_unknown_code_becomes_the_base_class() -> None:
    exc = Error("FUTURE_CODE", "from a newer server", True).to_exception()
    assert type(exc) is ProtocolError and exc.code == "FUTURE_CODE" and exc.fatal
    assert ProtocolError.for_code("NO_SUCH_CODE") is ProtocolError
