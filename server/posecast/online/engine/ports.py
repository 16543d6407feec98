"""The engine's ports: what it asks of an inference backend (STYLE principle 5).

The protocols here are what a backend implements; :mod:`posecast.online.inference.auto`
builds one by name.

A tick needs two things done for all ``R = P * N`` candidate rows: the decoder step
(:class:`StepDecoder`) and the candidate pool's FK, contact IK and anomaly error
(:class:`Pool`), and then the heaviest passes of each player's shown pose (``Pool.emit``,
``Pool.upper_body``, ``Pool.hinge``: a pool is a :class:`posecast.body.passes.Passes`,
which :func:`posecast.body.pipeline.show` runs them in). A backend supplies both; the
engine calls nothing else. Backends:

* ``native``: the C extension ``posecast._native`` (fused GRU step, FK, IK and scoring
  on one thread pool; :mod:`posecast.online.inference.native`), the default where it
  loads;
* ``onnx``: ONNX Runtime for the networks, numpy for the geometry (the reference);
* ``torch``: the training code's own ``CVAEDecoder.step`` (parity and research).

All read the same artifacts (ONNX + JSON sidecar): the ONNX file is the one source of
weights. This module imports no inference library.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.ik import MAX_DRIFT_M, RELEASE_FRAMES
from posecast.body.passes import Passes
from posecast.body.passes import PoolIK as PoolIK  # the pool's contact-IK state, re-exported
from posecast.body.pelvis import PelvisPoses

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

BACKENDS = ("native", "onnx", "torch")
MAX_THREADS = 64  # a backend's pool at most: the native kernels' (server/native/pc_threads.c)


class StepDecoder(Protocol):
    """One step of the CVAE decoder for ``R`` rows."""

    name: str
    meta: dict[str, Any]  # the sidecar
    cache_width: int  # columns of a row's latent cache

    def cache_latents(self, eps: F32) -> F32:
        """The per-row latent cache ``(n, cache_width)`` of latents ``eps (n, latent)``.

        Computed when a player joins (and for interpolated latents); a backend may
        keep ``eps`` itself or precompute the latent part of the first layer. The map
        is linear, so a blend of caches is the cache of the blend.
        """
        ...

    def step(self, features: F32, group: int, cache: F32, h: F32, out: Mapping[str, F32]) -> None:
        """Decode ``R = len(features) * group`` rows into ``out`` in place.

        ``features (G, F)``: raw (un-normalised) features, row ``g`` shared by rows
        ``g * group .. (g + 1) * group - 1``; ``cache (R, cache_width)``; ``h (R, H)``.
        ``out``: float32 C-contiguous ``"rotations" (R, 108)``, ``"contacts" (R, 2)``
        (probabilities), ``"h_out" (R, H)``, and ``"root" (R, 9)`` when the model
        predicts the pelvis.
        """
        ...


class Pool(Passes, Protocol):
    """FK, contact IK and anomaly error of every candidate row; and, a
    :class:`~posecast.body.passes.Passes`, the shown poses' FK and display IK, upper-body
    pass and hinges."""

    threshold_m: float  # the anomaly error above which a pose counts as implausible

    def step(
        self, rotations: F32, contacts: F32, pelvis: PelvisPoses, ik: PoolIK, world_out: F32
    ) -> F64:
        """Score ``R`` rows; returns the anomaly errors ``(R,)`` in metres.

        ``rotations (R, 108)`` 6D, ``contacts (R, 2)``; ``pelvis``: the rows' pelvis poses,
        each shared by ``pelvis.group`` rows (``N`` with a waist tracker, ``1`` when every
        sample has its own pelvis). The post-IK world positions go into ``world_out (R,
        19, 3)``; ``ik`` steps in place.
        """
        ...


@dataclass(frozen=True)
class Models:
    """What every backend's loader takes: the artifacts of one layout (names, and the
    folder, ``None`` for the shipped models), its thread count, and the pool's
    contact-IK settings (``EngineConfig.ik_release_frames``, ``ik_max_drift_m``)."""

    decoder: str
    anomaly: str
    models_dir: str | Path | None = None
    threads: int = 1
    release_frames: int = RELEASE_FRAMES
    max_drift_m: float | None = MAX_DRIFT_M
