# syntax=docker/dockerfile:1
# The posecast serving image: `posecast serve` with the shipped ONNX models, ONNX
# Runtime and the Redis client (posecast[redis]); no torch, no compiler, not root.
# Configuration is by environment only (POSECAST_*, docs/server.md), e.g.
#   docker build -t posecast .
#   docker run -e POSECAST_TOKEN_SECRET="$(openssl rand -base64 32)" -p 8765:8765 posecast
# tests/system/deploy checks this file (hadolint, structure) and runs its ENTRYPOINT with the
# compose environment outside Docker.

ARG PYTHON_IMAGE=python:3.11-slim-bookworm

# --- build: a virtualenv with posecast[redis] and its wheels ------------------------
FROM ${PYTHON_IMAGE} AS build
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1
# A C compiler for the native kernels (setup.py); only this stage has it.
# hadolint ignore=DL3008
RUN apt-get update \
 && apt-get install -y --no-install-recommends gcc libc6-dev \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
RUN python -m venv /opt/posecast
COPY pyproject.toml setup.py README.md LICENSE ./
COPY server ./server
# The models are package data (server/posecast/artifacts), so installing the package
# bakes them in; the checks fail the build if they, or the Redis client, are missing
# or if torch slipped into the serving install.
RUN /opt/posecast/bin/pip install ".[redis]" \
 && /opt/posecast/bin/python -c "import importlib.resources as r, posecast.online.cluster.redis_bus, onnxruntime; assert r.files('posecast').joinpath('artifacts/cvae_decoder.onnx').is_file(); from posecast import _native; print('native kernels:', _native.isas())" \
 && if /opt/posecast/bin/python -c "import torch" 2>/dev/null; then echo "torch in the serving image" >&2; exit 1; fi

# --- runtime: the virtualenv on a clean slim image ------------------------------------
FROM ${PYTHON_IMAGE} AS runtime
RUN groupadd --system --gid 10001 posecast \
 && useradd --system --uid 10001 --gid posecast --no-create-home --shell /usr/sbin/nologin posecast
COPY --from=build /opt/posecast /opt/posecast
ENV PATH=/opt/posecast/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    POSECAST_HOST=0.0.0.0 \
    POSECAST_PORT=8765
USER 10001:10001
EXPOSE 8765
# SIGTERM starts the graceful drain (bye to everyone, drain_timeout_s, exit 0).
STOPSIGNAL SIGTERM
HEALTHCHECK --interval=10s --timeout=3s --start-period=30s --retries=3 \
  CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('POSECAST_PORT', '8765'), timeout=2)"]
ENTRYPOINT ["posecast", "serve"]
