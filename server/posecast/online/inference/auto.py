"""Choose the inference backend by name (like uvicorn's ``auto``): the one place that
turns ``native``, ``onnx`` or ``torch`` into a decoder and a candidate pool (the
protocols of :mod:`posecast.online.engine.ports`).

Each backend lives in its own module and none imports another's runtime: ``torch`` is
imported only when asked for (a serving install has none), ``native`` only through
its adapter, :mod:`posecast.online.inference.native`. ``native`` is the default; where
the extension does not load (not built, or refusing the models) the engine falls back
to ``onnx`` and says so in one warning line.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import NamedTuple

from posecast.errors import ConfigError, ModelError
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ports import BACKENDS, MAX_THREADS, Models, Pool, StepDecoder
from posecast.tracking.layouts import Layout, spec

log = logging.getLogger("posecast.engine")


class Backend(NamedTuple):
    """What :func:`load_backend` built: ``name`` is the backend that runs (``onnx`` when
    ``native`` was asked for and fell back)."""

    name: str
    decoder: StepDecoder
    pool: Pool


def check_backend(name: str) -> str:
    """``name`` if it names a backend, else a :class:`ConfigError` listing them."""
    if name not in BACKENDS:
        exc = ConfigError(f"unknown backend {name!r}")
        exc.add_note(f"hint: pick one of {', '.join(BACKENDS)} (default native)")
        raise exc
    return name


def load_backend(
    name: str,
    layout: str = Layout.HMD3_WAIST,
    models_dir: str | Path | None = None,
    threads: int = 1,
    cfg: EngineConfig | None = None,
) -> Backend:
    """The backend ``name`` on the models of ``layout`` (shipped, or in ``models_dir``).

    ``threads``: intra-op threads of the backend's thread pool (``torch``'s decoder
    always runs on one). ``cfg`` gives the pool's contact-IK settings. Raises
    :class:`ConfigError` for an unknown name or a backend whose packages are missing,
    :class:`ModelError` for models it cannot load.
    """
    check_backend(name)
    if not 1 <= threads <= MAX_THREADS:
        exc = ConfigError(f"{threads} threads: the engine's pool takes 1 to {MAX_THREADS}")
        exc.add_note(f"hint: pass --threads (posecast serve: --engine-threads) 1 to {MAX_THREADS}")
        raise exc
    ls = spec(layout)
    cfg = cfg or EngineConfig()
    models = Models(ls.decoder, ls.anomaly, models_dir, threads, cfg.ik_release_frames,
                    cfg.ik_max_drift_m)  # fmt: skip
    if name == "native":
        try:
            from posecast.online.inference.native import load_native

            return Backend("native", *load_native(models))
        except (ImportError, ModelError) as exc:
            log.warning(
                "native backend unavailable (%s: %s); using onnx",
                type(exc).__name__,
                exc,
                extra={"backend": "onnx", "asked": "native"},
            )
    if name == "torch":
        try:
            import onnx  # noqa: F401
            import torch  # noqa: F401
        except ImportError as exc:
            missing = ConfigError(f"the torch backend needs the {exc.name!r} package")
            missing.add_note("hint: pip install 'posecast[train]', or pick --backend onnx")
            raise missing from None
        from posecast.online.inference.torch_backend import load_torch

        return Backend("torch", *load_torch(models))
    from posecast.online.inference.onnx_backend import load_onnx

    return Backend("onnx", *load_onnx(models))
