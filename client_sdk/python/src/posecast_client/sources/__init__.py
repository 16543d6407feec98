"""Tracker sources: where a headset's frames come from.

* :class:`WalkSource` - the built-in fixture, a procedural walk (no files needed)
* :class:`BvhReplaySource` - a BVH clip replayed at 60 Hz, with optional noise and dropouts
* :class:`SerialTrackerSource` - a device on a serial port (``proto/devices.md``)
* :class:`HidTrackerSource` - a USB HID device (``proto/devices.md``)

Every source is an async iterator of :class:`TrackerSample`; feed one to
:meth:`posecast_client.Client.stream`.
"""

from posecast_client.sources.base import TrackerSample, TrackerSource
from posecast_client.sources.devices import HidTrackerSource, SerialTrackerSource
from posecast_client.sources.replay import (
    RIGS,
    BvhReplaySource,
    BvhRig,
    ReplaySource,
    WalkSource,
)

__all__ = [
    "RIGS",
    "BvhReplaySource",
    "BvhRig",
    "HidTrackerSource",
    "ReplaySource",
    "SerialTrackerSource",
    "TrackerSample",
    "TrackerSource",
    "WalkSource",
]
