"""Where the shown pose's heaviest passes run: :class:`Passes`, and the numpy reference.

Three steps of :func:`posecast.body.pipeline.show` have a native port in
``posecast._native``: the FK of the shown rows with their display contact IK
(``emit``), the upper-body pass (``upper_body``, ``pc_upper.c``) and the knee and elbow
hinges (``hinge``). :class:`Passes` is what ``show`` asks of them; :class:`NumpyPasses`
is the reference every port is held to, line for line. An inference backend's
candidate pool is a :class:`Passes` too (``posecast.online.engine.ports.Pool``): the
backend chosen by name (``native``, ``onnx``, ``torch``; ``load_backend`` in
``posecast.online.inference.auto``) decides where these passes run, ``native`` in
C and the others in this module's numpy. Nothing here imports an inference library.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.batch_fk import fk32
from posecast.body.hinge import Limbs, hinge_quat
from posecast.body.ik import MAX_DRIFT_M, RELEASE_FRAMES, ContactIK
from posecast.body.upper_ik import solve_upper_body
from posecast.geometry.rotations import mat2quat

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass
class PoolIK:
    """Contact-IK state of ``R`` rows: a candidate pool's samples, or the shown poses'
    players (views or gathered copies of the engine's slot arrays, updated in place):
    ``locked (R, 2) bool``, ``lock_pos (R, 2, 3) float64``, ``release (R, 2) int64``,
    ``suppressed (R, 2) bool``."""

    locked: NDArray[np.bool_]
    lock_pos: F64
    release: NDArray[np.int64]
    suppressed: NDArray[np.bool_]

    @classmethod
    def zeros(cls, n: int) -> PoolIK:
        """The state of ``n`` rows that hold no foot."""
        return cls(
            np.zeros((n, 2), np.bool_),
            np.zeros((n, 2, 3)),
            np.zeros((n, 2), np.int64),
            np.zeros((n, 2), np.bool_),
        )


class Passes(Protocol):
    """The shown pose's FK and display IK, upper-body pass and hinges."""

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
        :func:`posecast.body.upper_ik.solve_upper_body` (the reference, which
        documents the arguments), in whatever this implementation runs it in."""
        ...

    def hinge(self, positions: F32, rotations: F32, limbs: Limbs) -> None:
        """The limbs ``limbs`` of the ``E`` shown poses onto their hinges, rotations
        changed in place: exactly :func:`posecast.body.hinge.hinge_quat`.
        ``rotations`` must be a writable C-contiguous float32 array (as ``emit`` and
        ``upper_body`` return them; ``native`` raises ``ValueError`` on any other
        rather than write into a copy), ``positions`` float32, and no joint may belong
        to two limbs."""
        ...


class NumpyPasses:
    """:class:`Passes` in numpy: the reference (``release_frames``, ``max_drift_m``: the
    contact IK's settings, ``EngineConfig.ik_release_frames`` and ``ik_max_drift_m``)."""

    def __init__(
        self, release_frames: int = RELEASE_FRAMES, max_drift_m: float | None = MAX_DRIFT_M
    ) -> None:
        self.release_frames = release_frames
        self.max_drift_m = max_drift_m

    def emit(
        self, rotations: F32, contacts: F32, root_mat: F32, root_pos: F32, ik: PoolIK
    ) -> tuple[F32, F32]:
        wm, wp = fk32(rotations, root_mat, root_pos)
        assert wm is not None
        ContactIK(
            ik.locked, ik.lock_pos, ik.release, self.release_frames, ik.suppressed, self.max_drift_m
        ).step(wm, wp, contacts)
        quats: F32 = mat2quat(wm).astype(np.float32)
        return wp, quats

    upper_body = staticmethod(solve_upper_body)  # the reference itself

    def hinge(self, positions: F32, rotations: F32, limbs: Limbs) -> None:
        hinge_quat(positions, rotations, limbs)
