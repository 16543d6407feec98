"""posecast client SDK: stream VR trackers to a posecast server, receive full-body poses.

Quick start (a dev server prints its token secret: ``posecast serve --dev``)::

    import posecast_client as pc

    token = pc.mint_token(secret, room="lobby", player="ada")
    async with pc.connect("ws://127.0.0.1:8765/", token) as client:
        await client.join("lobby", "Ada")
        streaming = asyncio.create_task(client.stream(pc.WalkSource(seconds=3.0)))
        async for event in client.events(until=streaming):
            if isinstance(event, pc.Pose):
                print(event.player, event.positions[pc.Joint.HEAD])

Layers: :mod:`~posecast_client.codec` (bytes <-> messages, pure),
:mod:`~posecast_client.session` (protocol state, pure), :mod:`~posecast_client.client`
(the asyncio shell, on :mod:`~posecast_client.link` and :mod:`~posecast_client.dial`),
:mod:`~posecast_client.sources` (trackers: replay, serial, HID),
:mod:`~posecast_client.recording` (room recordings and BVH export),
:mod:`~posecast_client.interp` (a jitter buffer: smooth poses at any display rate),
:mod:`~posecast_client.conventions` (Unity, Unreal and three.js frames; bone names).
"""

from posecast_client.client import Client, Connecting, connect
from posecast_client.clock import ClockSample, ClockSync
from posecast_client.codec import decode, encode, to_wire
from posecast_client.conventions import (
    BONE_RIGS,
    BONES,
    FRAMES,
    Engine,
    EngineFrame,
    EnginePose,
    engine2pos,
    engine2quat,
    head2xrview_quat,
    pos2engine,
    pose2engine,
    quat2engine,
)
from posecast_client.errors import (
    ERRORS,
    BvhError,
    ClientClosedError,
    ConfigInvalidError,
    ConnectFailedError,
    ConnectionLostError,
    PosecastClientError,
    ProtocolError,
    RecordingError,
    TokenProviderError,
)
from posecast_client.interp import (
    DEFAULT_INTERP,
    InterpConfig,
    InterpolatedPose,
    Interpolator,
    PoseBuffer,
    quat_slerp,
)
from posecast_client.protocol import (
    DEFAULT_LIMITS,
    SUBPROTOCOL,
    SUBPROTOCOL_V2,
    SUBPROTOCOLS,
    Bye,
    Calibrate,
    Error,
    Forecast,
    Frame,
    Hello,
    Kick,
    Layout,
    Limits,
    Member,
    Message,
    Ping,
    Pong,
    Pose,
    PoseRate,
    Poses,
    Presence,
    Resync,
    Selector,
    Skeleton,
    Welcome,
    seq_delta,
    seq_next,
)
from posecast_client.session import Event, Reconnecting, Stats
from posecast_client.skeleton import JOINT_NAMES, Joint, TrackerSlot
from posecast_client.sources import (
    BvhReplaySource,
    HidTrackerSource,
    ReplaySource,
    SerialTrackerSource,
    TrackerSample,
    TrackerSource,
    WalkSource,
)
from posecast_client.tokens import mint_token

__version__ = "0.1.0"

__all__ = [
    "BONES",
    "BONE_RIGS",
    "DEFAULT_INTERP",
    "DEFAULT_LIMITS",
    "ERRORS",
    "FRAMES",
    "JOINT_NAMES",
    "SUBPROTOCOL",
    "SUBPROTOCOLS",
    "SUBPROTOCOL_V2",
    "BvhError",
    "BvhReplaySource",
    "Bye",
    "Calibrate",
    "Client",
    "ClientClosedError",
    "ClockSample",
    "ClockSync",
    "ConfigInvalidError",
    "ConnectFailedError",
    "Connecting",
    "ConnectionLostError",
    "Engine",
    "EngineFrame",
    "EnginePose",
    "Error",
    "Event",
    "Forecast",
    "Frame",
    "Hello",
    "HidTrackerSource",
    "InterpConfig",
    "InterpolatedPose",
    "Interpolator",
    "Joint",
    "Kick",
    "Layout",
    "Limits",
    "Member",
    "Message",
    "Ping",
    "Pong",
    "Pose",
    "PoseBuffer",
    "PoseRate",
    "PosecastClientError",
    "Poses",
    "Presence",
    "ProtocolError",
    "Reconnecting",
    "RecordingError",
    "ReplaySource",
    "Resync",
    "Selector",
    "SerialTrackerSource",
    "Skeleton",
    "Stats",
    "TokenProviderError",
    "TrackerSample",
    "TrackerSlot",
    "TrackerSource",
    "WalkSource",
    "Welcome",
    "connect",
    "decode",
    "encode",
    "engine2pos",
    "engine2quat",
    "head2xrview_quat",
    "mint_token",
    "pos2engine",
    "pose2engine",
    "quat2engine",
    "quat_slerp",
    "seq_delta",
    "seq_next",
    "to_wire",
]
