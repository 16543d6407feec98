"""Single-sample reconstruction of whole clips, for evaluation (the engine does it live).

Frames go through the decoder one step at a time exactly as the server steps them,
then FK with the root from the waist tracker (or, for the headset-only model, from
its own pelvis outputs); the shown pose's passes are the engine's own
(:func:`posecast.body.pipeline.show`, run by :func:`~posecast.offline.evaluation.runner.run_shown`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import quat2mat, r6d2mat
from posecast.offline.dataset.frames import Frames
from posecast.online.inference.artifact import Artifact
from posecast.skeleton import NUM_ROTATIONS, reference_offsets

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


def decode_cvae(dec: Artifact, features: F32, z: F32) -> tuple[F64, F64, F64 | None]:
    """Decoder over a clip with a fixed latent: ``(T, F)``, ``(30,)`` ->
    ``(rot6d (T, 18, 6), contact probabilities (T, 2), pelvis outputs (T, 9) or None)``."""
    hidden = int(dec.meta["model_config"]["hidden"])
    h = np.zeros((1, hidden), np.float32)
    zz = np.asarray(z, np.float32)[None]
    rots, cons, roots = [], [], []
    for t in range(len(features)):
        out = dec.run(features=features[t : t + 1].astype(np.float32), z=zz, h=h)
        rots.append(out[0][0])
        cons.append(out[-2][0])
        if len(out) == 4:  # rotations, root, contacts, h_out
            roots.append(out[1][0])
        h = out[-1]
    rot = np.stack(rots).reshape(-1, NUM_ROTATIONS, 6).astype(np.float64)
    return rot, np.stack(cons), np.stack(roots).astype(np.float64) if roots else None


def decode_ae(step: Artifact, features: F32) -> tuple[F64, F64]:
    """The deterministic AE (encoder and decoder) over a clip."""
    hidden = int(step.meta["model_config"]["hidden"])
    he = np.zeros((1, hidden), np.float32)
    hd = np.zeros((1, hidden), np.float32)
    rots, cons = [], []
    for t in range(len(features)):
        rot, con, he, hd = step.run(
            features=features[t : t + 1].astype(np.float32), h_enc=he, h_dec=hd
        )
        rots.append(rot[0])
        cons.append(con[0])
    return np.stack(rots).reshape(-1, NUM_ROTATIONS, 6).astype(np.float64), np.stack(cons)


def pose_from_rotations(rot6d: F64, root_mat: F64, root_pos: F64) -> tuple[F64, F64]:
    """FK on the reference body from the pelvis pose ``(T, 3, 3)`` / ``(T, 3)`` (the
    waist tracker's, or a model's own) -> world ``(mat, pos)``."""
    local = np.concatenate([root_mat[:, None], r6d2mat(rot6d)], axis=1)
    return fk_mat(local, root_pos, reference_offsets())


def clip_truth(fr: Frames) -> tuple[F64, F64]:
    """Ground-truth world rotations ``(T, 19, 3, 3)`` and positions of a clip."""
    root = quat2mat(fr["root_quat"].astype(np.float64))
    return pose_from_rotations(
        fr["rot6d"].astype(np.float64), root, fr["root_pos"].astype(np.float64)
    )
