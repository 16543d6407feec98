"""The generated parts of the spec are what ``proto/generate_spec.py`` writes now: the
body's tables (``skeleton.md``, ``skeleton.json``) from the server's skeleton and
tracking modules, ``schema.json`` from ``fields.json``, and the README's token example
from the server's token code. A change to any of those sources without a regenerated
spec fails here."""

from __future__ import annotations

import json
from collections import Counter

import pytest

from posecast.online.auth.keys import KeySet
from posecast.online.auth.tokens import verify
from posecast.skeleton import JOINT_NAMES, PARENTS, reference_offsets
from posecast.tracking.features import TRACKER_JOINT_INDEX
from posecast.tracking.sites import SITE_JOINT_INDEX, SITES
from tests.proto.helpers import PROTO, load

GENERATED = load("generate_spec").build()


@pytest.mark.parametrize("name", sorted(GENERATED))
def test_generated_file_is_current(name: str) -> None:
    assert (PROTO / name).read_text("utf-8") == GENERATED[name], (
        f"proto/{name} is stale: run proto/generate_spec.py"
    )


def test_skeleton_json_is_the_servers_tables() -> None:
    """Spelled out once more against the modules, so a generator bug cannot hide."""
    body = json.loads((PROTO / "skeleton.json").read_text("utf-8"))
    joints = body["joints"]
    assert [j["name"] for j in joints] == list(JOINT_NAMES)
    assert [j["parent_index"] for j in joints] == list(PARENTS)
    assert [j["offset_m"] for j in joints] == reference_offsets().tolist()
    names = [j["name"] for j in joints]
    assert [names.index(s["joint"]) for s in body["tracker_slots"]] == list(TRACKER_JOINT_INDEX)
    assert [s["name"] for s in body["sites"]] == [s.value for s in SITES]
    assert [names.index(s["joint"]) for s in body["sites"]] == list(SITE_JOINT_INDEX)
    assert body["reference_body"]["height_m"] == 1.75


def test_skeleton_md_lists_every_joint_with_its_parent() -> None:
    text = (PROTO / "skeleton.md").read_text("utf-8")
    for j, p in enumerate(PARENTS):
        parent = "—" if p < 0 else f"`{JOINT_NAMES[p]}`"
        assert f"| {j} | `{JOINT_NAMES[j]}` | {parent} |" in text


def test_the_readme_token_example_verifies() -> None:
    gen = load("generate_spec")
    readme = (PROTO / "README.md").read_text("utf-8")
    block = readme.split(gen.TOKEN_BEGIN)[1].split(gen.TOKEN_END)[0]
    token = block.split("token = base64url(header)")[1].split("\n")[1].strip()
    keys = KeySet.from_secret(gen.EXAMPLE_SECRET, kid=gen.EXAMPLE_KID)
    claims = verify(keys, token, now=gen.EXAMPLE_NOW)
    assert (claims.room, claims.player, claims.jti) == ("lobby", "ada", gen.EXAMPLE_JTI)


def test_the_readme_counts_what_the_schema_cannot_tell() -> None:
    """README.md's table of reasons has the counts of schema_gaps.json."""
    gaps = json.loads((PROTO / "schema_gaps.json").read_text("utf-8"))["vectors"]
    readme = (PROTO / "README.md").read_text("utf-8")
    for reason, n in Counter(g["reason"] for g in gaps.values()).items():
        row = next(line for line in readme.splitlines() if line.startswith(f"| `{reason}` |"))
        assert row.endswith(f"| {n} |"), row
