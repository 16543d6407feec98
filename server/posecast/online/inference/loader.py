"""Engines on model artifacts: the edge where files become a running SSI engine.

``load_engine`` builds one :class:`~posecast.online.engine.ssi.Engine` for one tracker
layout; ``load_multi_engine`` one per layout, each on its own model, as the server
runs them (:class:`~posecast.online.engine.multi.MultiEngine`).
"""

from __future__ import annotations

from collections.abc import Iterable

from posecast.online.engine.anomaly import AnomalyScorer
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.ssi import Engine
from posecast.online.inference.artifact import load_artifact
from posecast.tracking.layouts import Layout, spec


def load_engine(
    cfg: EngineConfig | None = None,
    models_dir: str | None = None,
    threads: int = 1,
    layout: str = Layout.HMD3_WAIST,
) -> Engine:
    """An engine on the shipped models (or those in ``models_dir``) for ``layout``."""
    ls = spec(layout)
    decoder = load_artifact(ls.decoder, models_dir, threads=threads)
    scorer = AnomalyScorer(load_artifact(ls.anomaly, models_dir, threads=threads))
    return Engine(decoder, scorer, cfg)


def load_multi_engine(
    cfg: EngineConfig,
    layouts: Iterable[str],
    models_dir: str | None = None,
    threads: int = 1,
) -> MultiEngine:
    """One engine per layout in ``layouts``, each on its own shipped model."""
    return MultiEngine(
        {layout: load_engine(cfg, models_dir, threads, layout) for layout in layouts}
    )
