"""Helpers shared by the device tests: random tracker samples, what a decoder must
return for them, and frames or reports of which only the counters matter
(``test_framing.py`` for the pure framing, ``test_devices.py`` for the sources)."""

from __future__ import annotations

import numpy as np

from posecast_client.rotations import quat_normalize
from posecast_client.sources import TrackerSample
from posecast_client.sources.framing import (
    encode_hid_report,
    encode_hid_sites_report,
    encode_serial_frame,
    encode_serial_sites,
)

Sent = dict[int, tuple[np.ndarray, np.ndarray, int]]


def random_sample(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
    pos = rng.uniform(-3.0, 3.0, (4, 3))
    quat = quat_normalize(rng.normal(size=(4, 4)))
    return pos, quat, int(rng.integers(0, 16))


def expected(pos: np.ndarray, quat: np.ndarray, valid: int, step: float | None) -> np.ndarray:
    """What a decoder must return: the wire precision, untracked slots as identity."""
    if step is None:  # float32 on the serial line
        p, q = pos.astype(np.float32).astype(np.float64), quat.astype(np.float32).astype(np.float64)
    else:  # HID: millimetres and int16 quaternions
        p, q = np.rint(pos * 1000) * 0.001, np.rint(quat * 32767) / 32767
    for i in range(4):
        if not valid >> i & 1:
            p[i], q[i] = 0.0, (0.0, 0.0, 0.0, 1.0)
    return np.hstack([p, q])


def assert_sample(s: TrackerSample, sent: Sent, step: float | None) -> None:
    assert s.device_seq is not None and s.device_seq in sent, s.device_seq
    pos, quat, valid = sent[s.device_seq]
    assert s.valid == valid
    got = np.hstack([s.positions, s.orientations])
    np.testing.assert_allclose(got, expected(pos, quat, valid, step), rtol=0, atol=1e-12)


SERIAL_PERIOD_US = 8_333  # a 120 Hz device


def one_frame(kind: str, seq: int, t_us: int) -> bytes:
    """A version-1 (four slots) or tracker-set serial frame; only its counters matter."""
    if kind == "slots":
        return encode_serial_frame(
            seq, t_us, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))
        )
    return encode_serial_sites(seq, t_us, ["head"], np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]]))


def assert_carried_on(samples: list[TrackerSample], period_us: int, atol: float) -> None:
    """Three samples from seq 40, a device reset, three from seq 0: seq carries on by
    one and device_t by one device period a step (the serial and HID cases alike)."""
    assert [s.device_seq for s in samples] == [40, 41, 42, 43, 44, 45]
    times = [s.device_t for s in samples if s.device_t is not None]
    np.testing.assert_allclose(np.diff(times), [period_us * 1e-6] * 5, rtol=0, atol=atol)


PERIOD_US = 16_667  # a 60 Hz device


def one_report(kind: str, seq: int, t_us: int) -> bytes:
    """A version-1 (four slots) or tracker-set HID report; only its counters matter."""
    if kind == "slots":
        return encode_hid_report(seq, t_us, np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)))
    return encode_hid_sites_report(
        seq, t_us, ["head"], np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]])
    )


DEVICE_SITES = ("left_foot:imu", "head", "right_foot:imu", "left_hand", "right_hand", "waist")


PLAYER_SET = "head,left_hand,right_hand,waist,left_foot:imu,right_foot:imu,left_knee"


def random_set_sample(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    values = rng.uniform(-3.0, 3.0, (len(DEVICE_SITES), 3))
    values[[0, 2]] *= 5.0  # accelerations, m/s^2
    return values, quat_normalize(rng.normal(size=(len(DEVICE_SITES), 4)))
