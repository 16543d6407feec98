"""Engines on model artifacts: the edge where files become a running SSI engine.

``load_engine`` builds one :class:`~posecast.online.engine.ssi.Engine` for one tracker
layout; ``load_multi_engine`` one per layout, each on its own model, as the server
runs them (:class:`~posecast.online.engine.multi.MultiEngine`). Both run the backend
named (:mod:`posecast.online.inference.auto`); ``Engine.backend_name`` says which
one runs, ``onnx`` where ``native`` was asked for and could not load.
"""

from __future__ import annotations

from collections.abc import Iterable

from posecast.online.engine.config import EngineConfig
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.ssi import Engine
from posecast.online.inference.auto import load_backend
from posecast.tracking.layouts import Layout


def kernels(backend: str) -> dict[str, str]:
    """What the engine's arithmetic runs on, for logs, ``/metrics`` and reports: the
    native kernels' instruction-set level and GRU precision (``fp32``, ``bf16``,
    ``bf16-emulated``) where ``backend`` is ``native``; the other backends run fp32
    on their own kernels (``isa`` empty)."""
    if backend != "native":
        return {"isa": "", "precision": "fp32"}
    from posecast.online.inference.native import native_isa, native_precision

    return {"isa": native_isa(), "precision": native_precision()}


def load_engine(
    cfg: EngineConfig | None = None,
    models_dir: str | None = None,
    threads: int = 1,
    layout: str = Layout.HMD3_WAIST,
    backend: str = "native",
    capacity: int = 8,
) -> Engine:
    """An engine on the shipped models (or those in ``models_dir``) for ``layout``, on
    ``backend`` (``native``, ``onnx`` or ``torch``) with ``threads`` threads."""
    cfg = cfg or EngineConfig()
    b = load_backend(backend, layout, models_dir, threads, cfg)
    return Engine(b.decoder, b.pool, cfg, capacity, backend_name=b.name)


def load_multi_engine(
    cfg: EngineConfig,
    layouts: Iterable[str],
    models_dir: str | None = None,
    threads: int = 1,
    backend: str = "native",
) -> MultiEngine:
    """One engine per layout in ``layouts``, each on its own shipped model."""
    engines: dict[str, Engine] = {}
    for layout in layouts:
        engines[layout] = engine = load_engine(cfg, models_dir, threads, layout, backend)
        backend = engine.backend_name  # a fallback is taken (and logged) once, not per model
    return MultiEngine(engines)
