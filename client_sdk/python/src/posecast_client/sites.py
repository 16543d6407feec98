"""Tracker sets: which body sites a player tracks, and what each tracker reports.

A *tracker set* is a ``hello.layout`` that lists sites in the order the player's
``frame.sites`` rows come in, an inertial (IMU) site suffixed ``:imu``::

    head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu

Each row is ``[x, y, z, qx, qy, qz, qw]``: a *positional* tracker (headset, controller,
lighthouse tracker) sends its world position in metres, an *inertial* one its world
linear acceleration with gravity removed, m/s^2; both send their world orientation.
Head and both hands are required and positional. The server runs one model for every
set. These tables mirror the server's ``posecast.tracking.sites`` (a test compares
them when the server package is installed).
"""

from __future__ import annotations

from dataclasses import dataclass

from posecast_client.protocol import Layout
from posecast_client.skeleton import Joint

SITES: tuple[str, ...] = (
    "head",
    "left_hand",
    "right_hand",
    "waist",
    "left_foot",
    "right_foot",
    "left_knee",
    "right_knee",
    "left_elbow",
    "right_elbow",
)
# The joint each site's tracker sits on (its position; the orientation of that bone).
SITE_JOINTS: dict[str, Joint] = {
    "head": Joint.HEAD,
    "left_hand": Joint.LEFT_HAND,
    "right_hand": Joint.RIGHT_HAND,
    "waist": Joint.PELVIS,
    "left_foot": Joint.LEFT_FOOT,  # the ankle; the foot's rotation
    "right_foot": Joint.RIGHT_FOOT,
    "left_knee": Joint.LEFT_SHIN,  # the knee; the shin's rotation (strapped below it)
    "right_knee": Joint.RIGHT_SHIN,
    "left_elbow": Joint.LEFT_FOREARM,  # the elbow; the forearm's rotation
    "right_elbow": Joint.RIGHT_FOREARM,
}
REQUIRED = ("head", "left_hand", "right_hand")
INERTIAL_SUFFIX = ":imu"
MAX_SITES = len(SITES)


@dataclass(frozen=True)
class TrackerSet:
    """A parsed set: ``sites`` in wire order and, per site, whether it is inertial."""

    sites: tuple[str, ...]
    inertial: tuple[bool, ...]

    @classmethod
    def parse(cls, text: str) -> TrackerSet:
        """The set ``text`` names; ``ValueError`` says why not (the server's rule)."""
        if not isinstance(text, str) or not text:
            raise ValueError("a tracker set is a non-empty string")
        sites: list[str] = []
        inertial: list[bool] = []
        for token in text.split(","):
            imu = token.endswith(INERTIAL_SUFFIX)
            name = token[: -len(INERTIAL_SUFFIX)] if imu else token
            if name not in SITES:
                raise ValueError(f"unknown site {name!r}")
            if name in sites:
                raise ValueError(f"site {name!r} listed twice")
            sites.append(name)
            inertial.append(imu)
        for name in REQUIRED:
            if name not in sites or inertial[sites.index(name)]:
                missing = "positional " if name in sites else ""
                raise ValueError(f"a tracker set needs a {missing}{name!r} tracker")
        return cls(tuple(sites), tuple(inertial))

    @property
    def name(self) -> str:
        rows = zip(self.sites, self.inertial, strict=True)
        return ",".join(s + (INERTIAL_SUFFIX if i else "") for s, i in rows)

    def __str__(self) -> str:
        return self.name

    def __len__(self) -> int:
        return len(self.sites)

    @property
    def joints(self) -> tuple[Joint, ...]:
        """The joint each row's tracker sits on."""
        return tuple(SITE_JOINTS[s] for s in self.sites)

    @property
    def all_valid(self) -> int:
        """``frame.valid`` with every row tracked."""
        return (1 << len(self.sites)) - 1


def tracker_set(layout: str | None) -> TrackerSet | None:
    """The set a ``hello.layout`` names, or ``None`` for a named layout (``hmd3+waist``,
    ``hmd3``, absent); ``ValueError`` for neither."""
    if layout is None or layout in (Layout.HMD3_WAIST, Layout.HMD3):
        return None
    return TrackerSet.parse(layout)


def as_tracker_set(tracker_set: str | TrackerSet | None) -> TrackerSet | None:
    """A source's ``tracker_set`` argument: a set, a layout string naming one
    (``ValueError`` if it does not), or ``None`` (the four slots)."""
    if tracker_set is None or isinstance(tracker_set, TrackerSet):
        return tracker_set
    return TrackerSet.parse(tracker_set)
