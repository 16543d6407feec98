"""What goes into the engine and what comes out of a tick (pure data, numpy only).

These types cross layers: the protocol session builds :class:`TrackerFrame`, the
engine thread returns :class:`TickResult`, the hub routes :class:`EngineEvent`. They
live apart from :mod:`posecast.online.engine.ssi` so that importing them loads no
inference library.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TrackerFrame:
    """One frame from a headset: 4 trackers in slot order, world metres, xyzw (a
    headset-only player's waist slot is ignored)."""

    seq: int
    pos: F64  # (4, 3)
    quat: F64  # (4, 4)


@dataclass(frozen=True)
class PoseOut:
    """A reconstructed pose: the newest input's frame, or ``tau`` frames behind it
    with ``EngineConfig.delayed_emission`` (``seq`` says which)."""

    player: str
    seq: int  # seq of the tracker frame this pose is for
    positions: F32  # (19, 3) world metres, at the user's own scale
    rotations: F32  # (19, 4) world xyzw
    contacts: F32  # (2,)
    sample: int  # the latent sample shown (the destination during a transition)
    transitioning: bool
    held: bool  # the input was held over a missing frame
    # The tracker passes left the head, a hand or (a tracker set) a positional foot or
    # knee more than 1 mm from its tracker (out of the body's reach: bad calibration, a
    # thrown controller). A v2 record flag.
    reach_limited: bool = False
    # The calibration scale the positions were divided by (canonical metres per user
    # metre): FK of the rotations with the reference bones / scale gives the positions.
    scale: float = 1.0
    # A forecast (Engine.set_forecast): the pose is predicted this many milliseconds
    # after frame ``seq``'s time, not frame ``seq``'s own (0: it is frame ``seq``'s).
    ahead_ms: float = 0.0


class EngineEventKind(StrEnum):
    """What happened to a player's input; the value is the ``presence`` event it becomes."""

    STALE = "stale"  # no frame for ``EngineConfig.stale_after_frames`` frames
    ACTIVE = "active"  # frames again after ``STALE``


@dataclass(frozen=True)
class EngineEvent:
    kind: EngineEventKind
    player: str


@dataclass
class TickResult:
    poses: list[PoseOut]
    events: list[EngineEvent]
    transitions: int  # transitions started this tick, all players
