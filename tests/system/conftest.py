"""End-to-end behaviour suites: real servers (in process or ``posecast serve``
subprocesses) on loopback, real clients, the shipped models. Unlike the unit tests,
which mirror ``server/posecast/`` module for module, these are organised by behaviour:

- ``reliability/``: load, faults and hostile input (the ``reliability`` marker).
- ``scaleout/``: two or more nodes on a real ``redis-server``.
- ``deploy/``: the Dockerfile, Compose, Kubernetes, nginx and monitoring files.
- the files here: protocol v2 beside v1, mixed layouts in one room, every invalid
  vector over a connection, the WebSocket layer's refusals, graceful shutdown, and
  the live viewer in a browser.

The in-process server's engine fixtures are those of ``tests/online/conftest.py``.
"""

from __future__ import annotations

from tests.online.conftest import engine_factory, onnx_backend  # noqa: F401 (fixtures)
