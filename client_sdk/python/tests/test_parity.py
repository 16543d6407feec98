"""Differential fuzzing against the server's codec (a second implementation of the
same spec): mutated vectors must get the same verdict from both.

Where a message breaks several field rules at once, the spec lets each decoder
report any of them (``proto/README.md``, "Decoding order"), so only the verdict
kind is compared then. Skipped where the server package is not installed.
"""

from __future__ import annotations

import json
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import pytest

from posecast_client.codec import decode, encode

PROTO = Path(__file__).resolve().parents[3] / "proto"
FIELD_CODES = {"BAD_FIELD", "OUT_OF_RANGE", "NOT_NORMALISED", "VERSION_UNSUPPORTED"}
# The server says OUT_OF_RANGE for an empty or 33+ byte error.code; the spec gives
# code no byte bounds, only the pattern [A-Z][A-Z0-9_]{0,31}, so this SDK says
# BAD_FIELD (reported; no vector covers it yet).
KNOWN = {(("err", "OUT_OF_RANGE", "code"), ("err", "BAD_FIELD", "code"))}

Outcome = tuple[Any, ...]


def verdict(dec: Callable[[bytes], Any], enc: Callable[[Any], bytes], data: bytes) -> Outcome:
    try:
        msg = dec(data)
    except Exception as exc:
        return ("err", getattr(exc, "code", type(exc).__name__), getattr(exc, "field", None))
    return ("ok", enc(msg))


def mutate(data: bytes, rng: random.Random) -> bytes:
    if rng.random() < 0.5:  # bytes: overwrite, cut or insert a few
        b = bytearray(data)
        i = rng.randrange(len(b) + 1)
        how = rng.random()
        if how < 0.5 and b:
            b[min(i, len(b) - 1)] = rng.randrange(256)
        elif how < 0.75:
            del b[i : i + rng.randint(1, 4)]
        else:
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
        return bytes(b)
    try:  # values: swap one field for something else
        obj = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except ValueError:
        return data
    if not isinstance(obj, dict) or not obj:
        return data
    values = [None, True, 0, -1, 2**32, 1.5, float("nan"), "", "x" * 70, "A B", "\n",
              b"\x00", [], [1, 2, 3], {}, {"k": 1}, 7.0, 2**63, -(2**63)]  # fmt: skip
    obj[rng.choice(list(obj))] = rng.choice(values)
    out: bytes = msgpack.packb(obj, use_bin_type=True)
    return out


def test_the_sdk_and_the_server_agree_on_mutated_vectors() -> None:
    server = pytest.importorskip("posecast.online.protocol")
    files = sorted((PROTO / "vectors").glob("*.json"))
    cases = [c for f in files for c in json.loads(f.read_text("utf-8"))]
    # Message cases carry bytes; the v2 record-stream cases of poses.json carry streams.
    seeds = [
        bytes.fromhex(c.get("canonical_hex") or c["hex"])
        for c in cases
        if c.get("canonical_hex") or c.get("hex")
    ]
    assert len(seeds) > 100
    rng = random.Random(7)
    disagreements = []
    for _ in range(20_000):
        data = mutate(rng.choice(seeds), rng)
        ours = verdict(decode, encode, data)
        theirs = verdict(server.decode, server.encode, data)
        if ours == theirs or (theirs, ours) in KNOWN:
            continue
        both_fields = {ours[0], theirs[0]} == {"err"} and {ours[1], theirs[1]} <= FIELD_CODES
        if both_fields and ours[2] != theirs[2]:
            continue  # two rules broken: either may be reported
        disagreements.append((data.hex(), theirs, ours))
    assert not disagreements, disagreements[:5]
