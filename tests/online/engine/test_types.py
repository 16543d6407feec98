"""What goes into the engine and comes out of a tick (online.engine.types): the event
kinds are the wire's ``presence`` events, the data is frozen where it crosses layers,
and a pose's optional fields default to a plain, present pose."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from posecast.online.engine.types import (
    EngineEvent,
    EngineEventKind,
    PoseOut,
    TickResult,
    TrackerFrame,
)

SCHEMA = Path(__file__).resolve().parents[3] / "proto" / "schema.json"


def test_each_event_kind_is_a_presence_event_of_the_wire() -> None:
    """The hub sends ``Presence(ev.kind.value, ...)``: each value must be one the
    schema allows, in both protocol versions."""
    defs = json.loads(SCHEMA.read_text("utf-8"))["$defs"]
    for version in ("v1", "v2"):
        allowed = defs[f"{version}.presence"]["properties"]["event"]["enum"]
        assert {k.value for k in EngineEventKind} <= set(allowed), version
    assert EngineEventKind.STALE == "stale" and EngineEventKind.ACTIVE == "active"
    assert EngineEventKind("stale") is EngineEventKind.STALE


def test_frames_events_and_poses_are_frozen() -> None:
    frame = TrackerFrame(3, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)))
    event = EngineEvent(EngineEventKind.STALE, "p1")
    pose = PoseOut(
        "p1", 3, np.zeros((19, 3), np.float32), np.zeros((19, 4), np.float32),
        np.zeros(2, np.float32), sample=0, transitioning=False, held=False,
    )  # fmt: skip
    for value, name in ((frame, "seq"), (event, "player"), (pose, "seq")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(value, name, 4)


def test_a_pose_defaults_to_within_reach_at_scale_one_and_not_ahead() -> None:
    pose = PoseOut(
        "p1", 3, np.zeros((19, 3), np.float32), np.zeros((19, 4), np.float32),
        np.zeros(2, np.float32), sample=2, transitioning=True, held=False,
    )  # fmt: skip
    assert (pose.reach_limited, pose.scale, pose.ahead_ms) == (False, 1.0, 0.0)
    result = TickResult([pose], [EngineEvent(EngineEventKind.ACTIVE, "p1")], transitions=1)
    result.poses.append(pose)  # a tick's result is built up, not frozen
    assert len(result.poses) == 2 and result.events[0].kind == "active"
