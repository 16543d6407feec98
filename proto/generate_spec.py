"""Write the generated parts of the wire spec from the sources the server runs.

    .venv/bin/python proto/generate_spec.py           # rewrite the files
    .venv/bin/python proto/generate_spec.py --check   # exit 1 if one is stale

* ``skeleton.md`` and ``skeleton.json``: joints, parents, rest offsets, the reference
  body, tracker slots, sites, device frames and calibration (``_body.py``, from
  ``server/posecast/skeleton.py``, ``server/posecast/tracking/`` and the calibration);
* ``schema.json``: the JSON Schema (draft 2020-12) of every message of both versions,
  from ``fields.json`` (``_schema.py``);
* in ``README.md``, the worked token example between its markers, minted and verified
  by ``server/posecast/online/auth/tokens.py``.

``tests/proto/test_spec.py`` regenerates them in memory and compares, so the spec's
tables cannot drift from the code.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the helper modules beside this script

from _body import body_json, body_md  # noqa: E402
from _schema import Builder  # noqa: E402

from posecast.online.auth.keys import KeySet, SigningKey  # noqa: E402
from posecast.online.auth.tokens import mint, verify  # noqa: E402

TOKEN_BEGIN = "<!-- BEGIN token example: written by proto/generate_spec.py -->"
TOKEN_END = "<!-- END token example -->"
EXAMPLE_SECRET = "correct-horse-battery-staple-2026"  # 33 characters: at least 32
EXAMPLE_KID = "2026-01"
EXAMPLE_NOW = 1_767_225_600  # 2026-01-01T00:00:00Z
EXAMPLE_JTI = "bS3Vx0kq7RZ1Jm9a"  # what a minter's 12 random bytes look like in base64url


def dumps(value: Any, width: int = 100) -> str:
    """JSON with one-space indents, each container on one line where it fits ``width``."""

    def fmt(v: Any, indent: int, lead: int) -> str:
        flat = json.dumps(v, ensure_ascii=False)
        if not isinstance(v, (dict, list)) or not v or indent + lead + len(flat) <= width:
            return flat
        pad = " " * (indent + 1)
        if isinstance(v, dict):
            items = []
            for k, x in v.items():
                key = json.dumps(k, ensure_ascii=False) + ": "
                items.append(pad + key + fmt(x, indent + 1, len(key)))
            return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
        return (
            "[\n" + ",\n".join(pad + fmt(x, indent + 1, 0) for x in v) + "\n" + " " * indent + "]"
        )

    return fmt(value, 0, 0) + "\n"


def token_example() -> str:
    """The README's worked token example, minted and checked by the server's own code."""
    key = SigningKey.from_secret(EXAMPLE_SECRET, kid=EXAMPLE_KID)
    token = mint(key, room="lobby", player="ada", now=EXAMPLE_NOW, jti=EXAMPLE_JTI)
    keys = KeySet.from_secret(EXAMPLE_SECRET, kid=EXAMPLE_KID)
    verify(keys, token, now=EXAMPLE_NOW + 1)
    header_part, claims_part, sig = token.split(".")

    def text(part: str) -> str:
        return base64.urlsafe_b64decode(part + "=" * (-len(part) % 4)).decode("utf-8")

    signing_input = f"{header_part}.{claims_part}".encode("ascii")
    mac = hmac.new(EXAMPLE_SECRET.encode(), signing_input, hashlib.sha256).digest()
    assert base64.urlsafe_b64encode(mac).rstrip(b"=").decode() == sig
    return "\n".join(
        [
            TOKEN_BEGIN,
            "",
            f"HS256 with the secret `{EXAMPLE_SECRET}` (kid `{EXAMPLE_KID}`), for player",
            f"`ada` in room `lobby`, issued at {EXAMPLE_NOW} (2026-01-01 00:00 UTC) for an hour:",
            "",
            "```",
            "header (UTF-8 JSON):",
            f"  {text(header_part)}",
            "claims (UTF-8 JSON):",
            f"  {text(claims_part)}",
            "HMAC-SHA256(key = UTF-8 of the secret, message = ASCII of header.claims), hex:",
            f"  {mac.hex()}",
            'token = base64url(header) "." base64url(claims) "." base64url(MAC):',
            f"  {token}",
            "```",
            "",
            TOKEN_END,
        ]
    )


def with_token_example(readme: str) -> str:
    head, begin, rest = readme.partition(TOKEN_BEGIN)
    _, end, tail = rest.partition(TOKEN_END)
    if not begin or not end:
        raise SystemExit(f"README.md lacks the markers {TOKEN_BEGIN!r} ... {TOKEN_END!r}")
    return head + token_example() + tail


def build() -> dict[str, str]:
    """Every generated file's text, by its path under ``proto/``."""
    body = body_json()
    fields = json.loads((HERE / "fields.json").read_text("utf-8"))
    return {
        "skeleton.json": dumps(body),
        "skeleton.md": body_md(body),
        "schema.json": dumps(Builder(fields).schema()),
        "README.md": with_token_example((HERE / "README.md").read_text("utf-8")),
    }


def main(argv: list[str]) -> int:
    check = "--check" in argv
    stale = []
    for name, text in build().items():
        path = HERE / name
        if path.exists() and path.read_text("utf-8") == text:
            continue
        if check:
            stale.append(name)
        else:
            path.write_text(text, "utf-8")
            print(f"wrote proto/{name}")
    if stale:
        print("stale (run proto/generate_spec.py): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
