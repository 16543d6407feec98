"""The wire messages' constants and limits (online.protocol.messages): the limits a server
may lower, the roles' messages, the height range and sequence-number arithmetic."""

from __future__ import annotations

import pytest

from posecast.errors import ConfigError
from posecast.online.protocol import (
    DEFAULT_LIMITS,
    MESSAGE_TYPES,
    ROLE_MAY_SEND,
    ROLE_MAY_SEND_V2,
    SERVER_SENDS,
    SERVER_SENDS_V2,
    Limits,
    seq_delta,
    seq_next,
)
from posecast.online.protocol.messages import (
    LIMIT_RANGES,
    MAX_HEIGHT_M,
    MIN_HEIGHT_M,
    V1_TYPES,
    V2_TYPES,
)


def test_limits_default_to_the_v1_maxima_and_can_only_be_lowered() -> None:
    assert {k: getattr(DEFAULT_LIMITS, k) for k in LIMIT_RANGES} == {
        k: hi for k, (_, hi) in LIMIT_RANGES.items()
    }
    with pytest.raises(ConfigError):
        Limits(max_players=33)
    with pytest.raises(ConfigError):
        Limits(max_message_bytes=512)
    assert Limits(max_players=4).max_players == 4


def test_height_range_matches_the_engine() -> None:
    from posecast.online.engine import calibration

    assert (MIN_HEIGHT_M, MAX_HEIGHT_M) == (calibration.MIN_HEIGHT_M, calibration.MAX_HEIGHT_M)


def test_roles_cover_every_client_message() -> None:
    client = set().union(*ROLE_MAY_SEND.values())
    assert client | SERVER_SENDS == V1_TYPES
    assert client & SERVER_SENDS == {"bye"}
    assert all({"hello", "ping", "bye"} <= sends for sends in ROLE_MAY_SEND.values())
    client2 = set().union(*ROLE_MAY_SEND_V2.values())
    assert client2 | SERVER_SENDS_V2 == V2_TYPES == {cls.TYPE for cls in MESSAGE_TYPES} - {"pose"}
    assert client2 & SERVER_SENDS_V2 == {"bye"}


def test_sequence_numbers_wrap() -> None:
    assert seq_next(2**32 - 1) == 0
    assert seq_delta(0, 2**32 - 1) == 1
    assert seq_delta(5, 5) == 0
    assert seq_delta(4, 5) == -1
    assert seq_delta(2**31 - 1, 0) == 2**31 - 1
    assert seq_delta(2**31, 0) == -(2**31)  # half way round reads as old
