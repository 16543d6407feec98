"""The image's command, run outside Docker with the compose file's environment.

The Dockerfile's exact ENTRYPOINT + CMD and ENV, then node-a's environment from
docker-compose.yml, run on loopback: the virtualenv's ``bin`` stands in for the
image's ``/opt/posecast/bin``, a free port for 8765, and the test's real Redis for the
``redis`` service (whose name only resolves inside compose). Then the HEALTHCHECK
command runs with the same environment, and SIGTERM ends the process in time.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from tests.system.deploy.conftest import compose, dockerfile_stages, interpolate
from tests.system.scaleout.conftest import RedisServer, free_port


def _get(port: int, path: str) -> int:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
            return int(r.status)
    except urllib.error.HTTPError as e:
        return e.code


@pytest.mark.timeout(300)  # may include installing redis-server with apt-get
def test_image_command_serves_with_the_compose_environment(redis_server: RedisServer) -> None:
    image = dockerfile_stages()[-1]
    argv = image.exec_form("ENTRYPOINT") + image.exec_form("CMD")
    node = compose()["services"]["node-a"]
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSECAST_")}
    env.update({k: v for k, v in image.env().items() if k != "PATH"})
    env.update({k: interpolate(str(v), {}) for k, v in node["environment"].items()})
    env.update(
        PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}",
        POSECAST_HOST="127.0.0.1",  # loopback only, here
        POSECAST_PORT=str(port),
        POSECAST_REDIS_URL=redis_server.url,
        POSECAST_SAMPLES="8",  # start fast; the value does not change the wiring
    )
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert re.search(rf"listening on ws://127\.0\.0\.1:{port}", line), line
        assert _get(port, "/healthz") == 200
        deadline = time.monotonic() + 10
        while _get(port, "/readyz") != 200:
            assert time.monotonic() < deadline, "not ready with Redis up"
            time.sleep(0.05)
        check = subprocess.run(image.exec_form("HEALTHCHECK"), env=env, timeout=10)
        assert check.returncode == 0, "the image's HEALTHCHECK fails against the server"

        proc.send_signal(signal.SIGTERM)
        grace = float(node["stop_grace_period"].rstrip("s"))
        assert proc.wait(timeout=grace) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
