"""The engine's ports: what it asks of an inference backend (STYLE principle 5).

The protocols here are what a backend implements; :mod:`posecast.online.inference.auto`
builds one by name.

A tick needs two things done for all ``R = P * N`` candidate rows: the decoder step
(:class:`StepDecoder`) and the candidate pool's FK, contact IK and anomaly error
(:class:`Pool`), and then the shown pose of each player (``Pool.emit``, and the
upper-body pass and the hinges on it, ``Pool.upper_body`` and ``Pool.hinge``). A backend
supplies both; the engine calls nothing else. Backends:

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
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.online.engine.hinge import Limbs

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

BACKENDS = ("native", "onnx", "torch")
MAX_THREADS = 64  # a backend's pool at most: the native kernels' (server/native/pc_module.c)


@dataclass
class PoolIK:
    """Contact-IK state of ``R`` candidate rows (views into the engine's slot arrays,
    updated in place): ``locked (R, 2) bool``, ``lock_pos (R, 2, 3) float64``,
    ``release (R, 2) int64``, ``suppressed (R, 2) bool``."""

    locked: NDArray[np.bool_]
    lock_pos: F64
    release: NDArray[np.int64]
    suppressed: NDArray[np.bool_]


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


class Pool(Protocol):
    """FK, contact IK and anomaly error of every candidate row."""

    threshold_m: float  # the anomaly error above which a pose counts as implausible

    def step(
        self,
        rotations: F32,
        contacts: F32,
        root_mat: F32,
        root_pos: F32,
        group: int,
        ik: PoolIK,
        world_out: F32,
    ) -> F64:
        """Score ``R`` rows; returns the anomaly errors ``(R,)`` in metres.

        ``rotations (R, 108)`` 6D, ``contacts (R, 2)``; the pelvis ``root_mat (G, 3, 3)``
        and ``root_pos (G, 3)`` float32 with row ``g`` shared by ``group`` rows (``group
        = N`` with a waist tracker, ``1`` when every sample has its own pelvis). The
        post-IK world positions go into ``world_out (R, 19, 3)``; ``ik`` steps in place.
        """
        ...

    def emit(
        self, rotations: F32, contacts: F32, root_mat: F32, root_pos: F32, ik: PoolIK
    ) -> tuple[F32, F32]:
        """The shown poses of ``E`` rows (one per emitting player): FK with world
        rotations from ``rotations (E, 108)`` and the pelvis ``root_mat (E, 3, 3)`` /
        ``root_pos (E, 3)``, then the players' own display IK (``ik``, stepped in
        place; the thighs and shins swing with the feet). Returns world positions
        ``(E, 19, 3)`` and world rotations ``(E, 19, 4)`` xyzw, float32."""
        ...

    def upper_body(
        self,
        positions: F32,
        rotations: F32,
        tracker_pos: F64,
        tracker_quat: F64,
        free_root: NDArray[np.bool_] | None,
        wrist_share: float,
    ) -> tuple[F32, F32, NDArray[np.bool_]]:
        """Head and hands of the ``E`` shown poses onto their trackers: exactly
        :func:`posecast.online.engine.upper_ik.solve_upper_body` (the reference, which
        documents the arguments), in whatever this backend runs it in."""
        ...

    def hinge(self, positions: F32, rotations: F32, limbs: Limbs) -> None:
        """The limbs ``limbs`` of the ``E`` shown poses onto their hinges, rotations
        changed in place: exactly :func:`posecast.online.engine.hinge.hinge_quat`.
        ``rotations`` must be a writable C-contiguous float32 array (the engine's, as
        ``emit`` and ``upper_body`` return them; ``native`` raises ``ValueError`` on
        any other rather than write into a copy), ``positions`` float32, and no joint
        may belong to two limbs."""
        ...
