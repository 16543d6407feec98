"""The error table is proto/errors.json: one class per code, same defaults, same words."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from posecast_client import errors
from posecast_client.errors import ERRORS, ProtocolError
from posecast_client.protocol import Error

ERRORS_JSON = Path(__file__).resolve().parents[3] / "proto" / "errors.json"


@pytest.mark.skipif(not ERRORS_JSON.exists(), reason="proto/errors.json not found (repo only)")
def test_one_class_per_code_of_errors_json() -> None:
    rows = json.loads(ERRORS_JSON.read_text("utf-8"))
    assert list(ERRORS) == [r["code"] for r in rows]  # same codes, same order
    for row in rows:
        cls = ERRORS[row["code"]]
        assert (cls.fatal, cls.decoder) == (row["fatal"], row["decoder"]), row["code"]
        assert " ".join((cls.__doc__ or "").split()) == row["meaning"], row["code"]
        camel = "".join(w.capitalize() for w in row["code"].split("_")) + "Error"
        assert cls.__name__ == camel and getattr(errors, camel) is cls


def test_the_hierarchy_docstring_lists_every_class() -> None:
    doc = errors.__doc__ or ""
    for code, cls in ERRORS.items():
        assert f"{cls.__name__}" in doc and code in doc


def test_error_messages_map_to_typed_exceptions() -> None:
    exc = Error("KICKED", "bye", True, None, None).exception()
    assert isinstance(exc, errors.KickedError) and exc.fatal and not exc.retryable
    soft = Error("TIMED_OUT", "idle", False, "seq", 4).exception()  # the message overrides fatal
    assert isinstance(soft, errors.TimedOutError) and not soft.fatal and soft.retryable
    assert (soft.field, soft.ref_seq) == ("seq", 4)
    future = Error("SHINY_NEW_CODE", "?", True).exception()
    assert type(future) is ProtocolError and future.code == "SHINY_NEW_CODE" and future.fatal


def test_only_transient_endings_are_retryable() -> None:
    retryable = {code for code, cls in ERRORS.items() if cls.retryable}
    assert retryable == {"TIMED_OUT", "SLOW_CONSUMER", "SERVER_SHUTDOWN", "INTERNAL"}
    assert errors.ConnectionLostError.retryable
