"""A motion clip on the canonical skeleton: the unit every later stage works on."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import quat2mat
from posecast.skeleton import NUM_JOINTS, reference_offsets


@dataclass(frozen=True)
class CanonicalClip:
    """Canonical motion: local rotations, root path and the body it was made for.

    Attributes:
        name: clip id, e.g. ``"05_02"``.
        subject: the performer's id (the split is by subject).
        fps: frames per second.
        local_quat: ``(F, 19, 4)`` xyzw local rotations; joint 0 is the root's world
            rotation.
        root_pos: ``(F, 3)`` pelvis world position, metres.
        offsets: ``(19, 3)`` rest offsets of the body, metres (the reference body
            unless bone-length augmentation changed it).
    """

    name: str
    subject: str
    fps: float
    local_quat: NDArray[np.float64]
    root_pos: NDArray[np.float64]
    offsets: NDArray[np.float64] = field(default_factory=reference_offsets)
    rig: str = ""

    def __post_init__(self) -> None:
        f = self.local_quat.shape[0]
        if self.local_quat.shape != (f, NUM_JOINTS, 4) or self.root_pos.shape != (f, 3):
            raise ValueError(f"bad clip shapes {self.local_quat.shape} / {self.root_pos.shape}")

    @property
    def n_frames(self) -> int:
        return int(self.local_quat.shape[0])

    @property
    def seconds(self) -> float:
        return self.n_frames / self.fps

    def fk(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """World rotation matrices ``(F, 19, 3, 3)`` and positions ``(F, 19, 3)``."""
        wm, wp = fk_mat(quat2mat(self.local_quat), self.root_pos, self.offsets)
        return wm.astype(np.float64), wp.astype(np.float64)

    def with_(self, **changes: object) -> CanonicalClip:
        """A copy with some fields replaced."""
        return replace(self, **changes)  # type: ignore[arg-type]
