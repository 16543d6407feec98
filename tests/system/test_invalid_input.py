"""Every invalid vector in ``proto/vectors/`` sent by a connected player, end to end.

The cases of each protocol version go over a connection of that version (v2: a
``posecast.v2`` one, with the new messages and fields). Each gets its error code
(and field) back; a fatal one closes that connection only.
Meanwhile another player streams frames and a spectator watches: its pose stream
must go on, in order, through the whole barrage.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import pytest

from posecast.online.protocol.messages import Error, Welcome
from tests.online.conftest import make_cfg, token
from tests.online.wsclient import Client, Factory, serving

PROTO = Path(__file__).resolve().parents[2] / "proto"


def _invalid_vectors(version: int = 1) -> list[dict[str, Any]]:
    out = []
    for path in sorted((PROTO / "vectors").glob("*.json")):
        cases = json.loads(path.read_text("utf-8"))
        out += [v for v in cases if "hex" in v and version in v["versions"]]
    return out


def _fatal_codes() -> set[str]:
    return {e["code"] for e in json.loads((PROTO / "errors.json").read_text()) if e["fatal"]}


def test_the_vector_table_is_there() -> None:
    vectors = _invalid_vectors()
    assert len(vectors) >= 50
    assert {"MALFORMED", "TOO_LARGE", "BAD_FIELD", "OUT_OF_RANGE", "NOT_NORMALISED"} <= {
        v["error"] for v in vectors
    }


@pytest.mark.timeout(60)
@pytest.mark.parametrize("version", [1, 2])
def test_every_invalid_vector_gets_its_code_and_nobody_else_notices(
    engine_factory: Factory, version: int
) -> None:
    vectors, fatal = _invalid_vectors(version), _fatal_codes()

    async def scenario() -> None:
        cfg = make_cfg(lookahead=1, error_rate_hz=10_000.0)
        async with serving(cfg, engine_factory) as server:
            good, watcher = await Client.open(server.port), await Client.open(server.port)
            assert isinstance(await good.hello(token(player="good")), Welcome)
            assert isinstance(await watcher.hello(token(player="w", role="spectator")), Welcome)
            good.stream()
            await watcher.wait_for(lambda m: m.TYPE == "pose")
            t0, before = time.monotonic(), len(watcher.poses("good"))

            bad_token = token(player="bad")
            bad = await Client.open(server.port, version=version)
            await bad.hello(bad_token)
            mismatches = []
            for v in vectors:
                mark = len(bad.messages)
                await bad.send(bytes.fromhex(v["hex"]))
                err = await bad.error(start=mark)
                got = (err.code, err.field if "field" in v else None, err.fatal)
                want = (v["error"], v.get("field"), v["error"] in fatal)
                if got != want:
                    mismatches.append((v["name"], got, want))
                if err.fatal:
                    await asyncio.wait_for(bad.closed.wait(), 2)
                    bad = await Client.open(server.port, version=version)
                    assert isinstance(await bad.hello(bad_token), Welcome)
            assert mismatches == []

            seconds = time.monotonic() - t0
            await asyncio.sleep(0.2)
            seqs = [p.seq for p in watcher.poses("good")]
            assert seqs == sorted(seqs)
            assert len(seqs) - before >= 0.5 * 60 * seconds  # the stream kept its rate
            assert server.metrics.value("posecast_players") == 2
            errors = sum(
                server.metrics.value("posecast_errors_total", {"code": c})
                for c in {v["error"] for v in vectors}
            )
            assert errors == len(vectors)
            assert not [m for m in good.messages if isinstance(m, Error)]
            for cl in (good, watcher, bad):
                await cl.close()

    asyncio.run(scenario())
