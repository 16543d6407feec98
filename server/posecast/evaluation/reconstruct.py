"""Single-sample reconstruction of whole clips, for evaluation (the engine does it live).

Frames go through the decoder one step at a time exactly as the server steps them,
then FK with the root from the waist tracker, then optional contact IK.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from posecast.engine.ik import ContactIK
from posecast.geometry.kinematics import fk_mat
from posecast.geometry.rotations import quat2mat, r6d2mat
from posecast.inference.artifact import Artifact
from posecast.skeleton import NUM_ROTATIONS, reference_offsets

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


def decode_cvae(dec: Artifact, features: F32, z: F32) -> tuple[F64, F64]:
    """Decoder over a clip with a fixed latent: ``(T, 24)``, ``(30,)`` ->
    ``(rot6d (T, 18, 6), contact probabilities (T, 2))``."""
    hidden = int(dec.meta["model_config"]["hidden"])
    h = np.zeros((1, hidden), np.float32)
    zz = np.asarray(z, np.float32)[None]
    rots, cons = [], []
    for t in range(len(features)):
        rot, con, h = dec.run(features=features[t : t + 1].astype(np.float32), z=zz, h=h)
        rots.append(rot[0])
        cons.append(con[0])
    return np.stack(rots).reshape(-1, NUM_ROTATIONS, 6).astype(np.float64), np.stack(cons)


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


def pose_from_rotations(rot6d: F64, waist_pos: F64, waist_quat: F64) -> tuple[F64, F64]:
    """FK on the reference body, root from the waist tracker -> world ``(mat, pos)``."""
    local = np.concatenate([quat2mat(waist_quat)[:, None], r6d2mat(rot6d)], axis=1)
    return fk_mat(local, waist_pos, reference_offsets())


def contact_ik(world_mat: F64, world_pos: F64, contacts: F64) -> None:
    """Run the contact IK over a clip in place (one sample, frame by frame)."""
    ik = ContactIK.zeros(1)
    for t in range(len(world_pos)):
        ik.step(world_mat[t : t + 1], world_pos[t : t + 1], contacts[t : t + 1])
