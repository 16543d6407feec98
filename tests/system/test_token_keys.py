"""Key rotation on a real ``posecast serve``: the key set file is re-read on SIGHUP and
at ``--token-keys-reload-s``, without dropping anyone; a set that does not load is
counted and the old one stays. And ``posecast keygen`` / ``posecast token --key``
mint what such a server takes."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from posecast.online.auth.keys import SigningKey, generate
from posecast.online.auth.tokens import mint
from posecast.online.protocol.messages import Error, Welcome
from posecast.testing.serve import ServeProcess
from tests.online.conftest import SECRET
from tests.online.wsclient import Client


def _write(path: Path, *public: dict[str, object]) -> None:
    tmp = path.with_suffix(".tmp")  # written whole, then renamed: never half a file
    tmp.write_text(json.dumps({"keys": list(public)}))
    tmp.replace(path)


async def _hello(port: int, token: str, player: str) -> tuple[Client, object]:
    client = await Client.open(port)
    return client, await client.hello(token, room="r1", name=player)


def _until(
    server: ServeProcess, name: str, want: float, timeout_s: float = 10.0, **labels: str
) -> None:
    deadline = time.monotonic() + timeout_s
    while server.metric(name, **labels) != want:
        assert time.monotonic() < deadline, (name, labels, server.metric(name, **labels), want)
        time.sleep(0.05)


@pytest.mark.timeout(90)
def test_sighup_rotates_the_keys_and_keeps_the_players(tmp_path: Path) -> None:
    old_private, old_public = generate("EdDSA", "2026-11")
    new_private, new_public = generate("ES256", "2026-12")
    old, new = SigningKey.from_jwk(old_private), SigningKey.from_jwk(new_private)
    path = tmp_path / "keys.json"
    _write(path, old_public)
    with ServeProcess(secret=SECRET, env={"POSECAST_TOKEN_KEYS_FILE": str(path)}) as server:
        server.wait_ready()
        port = server.port

        async def scenario() -> None:
            now = time.time()
            stay, got = await _hello(port, mint(old, room="r1", player="stays", now=now), "stays")
            assert isinstance(got, Welcome)
            early, got = await _hello(port, mint(new, room="r1", player="early", now=now), "x")
            assert isinstance(got, Error) and "'2026-12' is unknown" in got.message
            await early.close()
            assert server.metric("posecast_token_keys") == 2  # the secret's and 2026-11

            # 1. Add the new key: both mint.
            _write(path, old_public, new_public)
            server.proc.send_signal(signal.SIGHUP)
            await asyncio.to_thread(
                _until, server, "posecast_token_key_reloads_total", 1, result="ok"
            )
            for key, who in ((new, "new-1"), (old, "old-1")):
                c, got = await _hello(port, mint(key, room="r1", player=who, now=now), who)
                assert isinstance(got, Welcome), (who, got)
                await c.close()

            # 2. After the longest token lifetime, drop the old key: its tokens stop.
            _write(path, new_public)
            server.proc.send_signal(signal.SIGHUP)
            await asyncio.to_thread(
                _until, server, "posecast_token_key_reloads_total", 2, result="ok"
            )
            c, got = await _hello(port, mint(old, room="r1", player="old-2", now=now), "old-2")
            assert isinstance(got, Error) and got.code == "UNAUTHENTICATED"
            await c.close()

            # A file that does not load: counted, logged, the set in force stays.
            path.write_text('{"keys": [')
            server.proc.send_signal(signal.SIGHUP)
            await asyncio.to_thread(
                _until, server, "posecast_token_key_reloads_total", 1, result="failed"
            )
            c, got = await _hello(port, mint(new, room="r1", player="new-2", now=now), "new-2")
            assert isinstance(got, Welcome)
            await c.close()

            # The player who joined with the old key before all this is still here.
            assert server.metric("posecast_players") == 1
            assert not stay.closed.is_set()
            await stay.close()

        asyncio.run(scenario())
        assert server.metric("posecast_token_refusals_total", reason="unknown_kid") == 2


@pytest.mark.timeout(60)
def test_the_reload_interval_picks_up_a_new_key(tmp_path: Path) -> None:
    private, public = generate("EdDSA", "later")
    path = tmp_path / "keys.json"
    _write(path, generate("EdDSA", "first")[1])
    env = {"POSECAST_TOKEN_KEYS_FILE": str(path), "POSECAST_TOKEN_KEYS_RELOAD_S": "0.2"}
    with ServeProcess(secret=SECRET, env=env) as server:
        server.wait_ready()
        _write(path, public)
        done = server.metric("posecast_token_key_reloads_total", result="ok")
        deadline = time.monotonic() + 10  # two reloads more: one began after the write
        while server.metric("posecast_token_key_reloads_total", result="ok") < done + 2:
            assert time.monotonic() < deadline, "no reload at the interval"
            time.sleep(0.05)

        async def scenario() -> object:
            token = mint(SigningKey.from_jwk(private), room="r1", player="p", now=time.time())
            c, got = await _hello(server.port, token, "p")
            await c.close()
            return got

        assert isinstance(asyncio.run(scenario()), Welcome)


def test_keygen_and_token_key_mint_for_a_server(tmp_path: Path) -> None:
    """``posecast keygen --out F`` writes the private JWK (0600) and prints the public
    set; ``posecast token --key F`` mints with it; a server holding the set verifies."""
    from posecast.online.auth.keys import parse_key_set
    from posecast.online.auth.tokens import verify

    env = {k: v for k, v in os.environ.items() if not k.startswith("POSECAST_")}
    out = tmp_path / "backend-key.json"

    def posecast(*argv: str) -> subprocess.CompletedProcess[str]:
        cmd = [sys.executable, "-m", "posecast", *argv]
        return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)

    gen = posecast("keygen", "--alg", "EdDSA", "--kid", "2026-12", "--out", str(out))
    assert gen.returncode == 0, gen.stderr
    assert out.stat().st_mode & 0o777 == 0o600
    public = parse_key_set(gen.stdout, "stdout")
    assert '"d"' not in gen.stdout and '"d"' in out.read_text()
    tok = posecast("token", "--key", str(out), "--room", "r", "--player", "p")
    assert tok.returncode == 0, tok.stderr
    assert verify(public, tok.stdout.strip(), now=time.time()).player == "p"

    again = posecast("keygen", "--kid", "k", "--out", str(out))
    assert again.returncode == 2 and "never overwrites" in again.stderr
    pub_file = tmp_path / "public.json"
    pub_file.write_text(json.dumps(json.loads(gen.stdout)["keys"][0]))
    refused = posecast("token", "--key", str(pub_file), "--room", "r", "--player", "p")
    assert refused.returncode == 2 and "public key" in refused.stderr
    wrong = posecast("token", "--key", str(out), "--alg", "HS256", "--room", "r", "--player", "p")
    assert wrong.returncode == 2 and "does not fit" in wrong.stderr
    assert "Traceback" not in refused.stderr + wrong.stderr + again.stderr
