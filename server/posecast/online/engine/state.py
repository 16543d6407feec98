"""The engine's per-player state, by name: what :class:`~posecast.online.engine.ssi.Engine`
keeps in its slot arrays (:mod:`posecast.online.engine.slots`), the shapes of each, and
which of them a recalibration re-expresses."""

from __future__ import annotations

import numpy as np

from posecast.online.engine.forecasting import HISTORY
from posecast.online.engine.slots import Spec
from posecast.skeleton import NUM_JOINTS
from posecast.tracking.layouts import LayoutSpec


def state_specs(
    N: int, latent: int, cache_width: int, hidden: int, layout: LayoutSpec, L: int
) -> dict[str, Spec]:
    """Every slot array of an engine with ``N`` samples, the decoder's ``latent``,
    ``cache_width`` and ``hidden`` widths, ``layout`` and ring rows ``L``."""
    n_root, rows = layout.root_outputs, layout.rows
    return {
        "eps": ((N, latent), np.float32),
        "zc": ((N, cache_width), np.float32),  # the decoder's latent cache
        "ik_locked": ((N, 2), np.bool_),
        "ik_lock_pos": ((N, 2, 3), np.float64),
        "ik_release": ((N, 2), np.int64),
        "ik_suppressed": ((N, 2), np.bool_),
        "disp_locked": ((2,), np.bool_),
        "disp_lock_pos": ((2, 3), np.float64),
        "disp_release": ((2,), np.int64),
        "disp_suppressed": ((2,), np.bool_),
        # The rest of the shown pose's state (body.pipeline.ShownState): the
        # toes' horizontal positions and averaged speeds, the reach's move,
        # the planted toes' shown positions and offsets.
        "disp_toe_xz": ((2, 2), np.float64),
        "disp_toe_speed": ((2,), np.float64),
        "disp_reach": ((3,), np.float64),
        "disp_plant_xz": ((2, 2), np.float64),
        "disp_plant_offset": ((2, 2), np.float64),
        "ring_h": ((N, hidden), np.float32, L),  # hidden state before the frame
        "ring_rot": ((N, 108), np.float32, L),
        "ring_con": ((N, 2), np.float32, L),
        "ring_x": ((layout.n_features,), np.float32, L),
        "ring_root": ((N, max(1, n_root)), np.float32, L),  # hmd3: pelvis outputs
        "ring_pos": ((rows, 3), np.float64, L),  # calibrated tracker positions
        "ring_quat": ((rows, 4), np.float64, L),
        "kinds": ((rows,), np.int8),  # sites: each row's Kind (0 elsewhere)
        "ring_rootm": ((3, 3), np.float32, L),  # the waist's rotation (waist layouts)
        "ring_seq": ((), np.int64, L),
        # The last shown poses, newest last, of players with a forecast.
        "fc_pos": ((HISTORY, NUM_JOINTS, 3), np.float32),
        "fc_rot": ((HISTORY, NUM_JOINTS, 4), np.float32),
        "ring_held": ((), np.bool_, L),
    }


# The shown pose's state per player, in body.pipeline.ShownState.arrays()'s order.
SHOWN = (
    "disp_locked",
    "disp_lock_pos",
    "disp_release",
    "disp_suppressed",
    "disp_toe_xz",
    "disp_toe_speed",
    "disp_reach",
    "disp_plant_xz",
    "disp_plant_offset",
)
# Per-sample shapes of the candidate pool's contact-IK state, in PoolIK's field order.
IK_SHAPES: dict[str, tuple[int, ...]] = {
    "locked": (2,),
    "lock_pos": (2, 3),
    "release": (2,),
    "suppressed": (2,),
}
# Tracker-space state re-expressed on a recalibration (Engine.set_calibration): the
# candidates' and the shown pose's contact locks, the clearance's toes, the reach's
# move, the planted toes.
RESCALED = (
    "ik_lock_pos",
    "disp_lock_pos",
    "disp_toe_xz",
    "disp_reach",
    "disp_plant_xz",
    "disp_plant_offset",
)
