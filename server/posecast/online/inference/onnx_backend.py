"""The ``onnx`` backend, the reference: ONNX Runtime for the networks, numpy for the geometry.

:class:`OnnxDecoder` runs the exported decoder step (``cvae_decoder*.onnx``) straight
into the engine's ring rows; its latent cache is ``eps`` itself. :class:`NumpyPool` is
the candidate pool of every backend that has no pool of its own (``torch`` too): the
float32 FK of :mod:`posecast.body.batch_fk`, the contact IK of
:mod:`posecast.body.ik` and the anomaly error of
:class:`posecast.online.inference.anomaly.AnomalyScorer` (whose network ONNX Runtime
runs); the shown poses' passes are the numpy references,
:class:`posecast.body.passes.NumpyPasses`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from posecast.body.batch_fk import fk32
from posecast.body.ik import MAX_DRIFT_M, RELEASE_FRAMES, ContactIK
from posecast.body.passes import NumpyPasses
from posecast.body.pelvis import PelvisPoses
from posecast.online.engine.ports import F32, F64, Models, PoolIK
from posecast.online.inference.anomaly import AnomalyScorer
from posecast.online.inference.artifact import Artifact, load_artifact


class OnnxDecoder:
    """A :class:`~posecast.online.engine.ports.StepDecoder` over an ONNX decoder artifact."""

    def __init__(self, artifact: Artifact) -> None:
        self.artifact = artifact
        self.name = artifact.name
        self.meta: dict[str, Any] = artifact.meta
        self.cache_width = int(artifact.meta["model_config"]["latent"])

    def cache_latents(self, eps: F32) -> F32:
        """The cache is the latent itself (the graph's ``z`` input), as float32."""
        return np.array(eps, dtype=np.float32)

    def step(self, features: F32, group: int, cache: F32, h: F32, out: Mapping[str, F32]) -> None:
        # The graph takes one feature row per decoded row: repeat each player's row
        # for its `group` samples. (P, F) -> (P * group, F)
        x = np.repeat(features, group, axis=0) if group > 1 else features
        self.artifact.run_into({"features": x, "z": cache, "h": h}, dict(out))


class NumpyPool(NumpyPasses):
    """A :class:`~posecast.online.engine.ports.Pool` in numpy (anomaly AE on ONNX Runtime).

    ``release_frames`` and ``max_drift_m`` are the contact-IK settings
    (``EngineConfig.ik_release_frames``, ``EngineConfig.ik_max_drift_m``).
    """

    def __init__(
        self,
        anomaly: Artifact,
        release_frames: int = RELEASE_FRAMES,
        max_drift_m: float | None = MAX_DRIFT_M,
    ) -> None:
        super().__init__(release_frames, max_drift_m)
        self.scorer = AnomalyScorer(anomaly)
        self.threshold_m = self.scorer.threshold_m

    def step(
        self, rotations: F32, contacts: F32, pelvis: PelvisPoses, ik: PoolIK, world_out: F32
    ) -> F64:
        root_mat, root_pos, group = pelvis
        if group > 1:  # FK wants one pelvis per row: (G, ...) -> (G * group, ...)
            mats, places = np.repeat(root_mat, group, axis=0), np.repeat(root_pos, group, axis=0)
        else:
            mats, places = root_mat, root_pos
        _, wp = fk32(rotations, mats, places, False)  # (R, 19, 3)
        ContactIK(
            ik.locked, ik.lock_pos, ik.release, self.release_frames, ik.suppressed, self.max_drift_m
        ).step(None, wp, contacts)
        world_out[...] = wp
        # The scorer's frame math runs once per pelvis, on the unrepeated (G, ...) rows.
        scores = self.scorer.score_mats(wp, root_pos, root_mat, repeat=group)
        return np.asarray(scores, dtype=np.float64)


def load_onnx(m: Models) -> tuple[OnnxDecoder, NumpyPool]:
    """The ``onnx`` backend on the artifacts ``m`` names."""
    dec = OnnxDecoder(load_artifact(m.decoder, m.models_dir, threads=m.threads))
    scorer = load_artifact(m.anomaly, m.models_dir, threads=m.threads)
    return dec, NumpyPool(scorer, m.release_frames, m.max_drift_m)
