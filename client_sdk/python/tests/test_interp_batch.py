"""The batched jitter buffer against the rules applied one pose at a time.

:meth:`Interpolator.poses_at` plans every player's sample, makes them in one batch,
reuses the last frame's sample where no pose changed it and fades corrections in one
batch; :class:`interp_reference.ReferenceBuffer` samples each player afresh every
frame. Over a lossy link (drops, poses overtaking each other, a burst after a stall,
a teleport, a rejoin with an older seq, players with and without rotations) at 90 Hz
both must show the same poses, frame by frame: mode, seq and shown time exactly,
positions and rotations within 1e-9.
"""

from __future__ import annotations

import numpy as np
import pytest

from interp_reference import ReferenceBuffer
from posecast_client.interp import InterpConfig, Interpolator, PoseBuffer
from posecast_client.protocol import Pose
from posecast_client.rotations import F64

POSE_HZ, DISPLAY_HZ, T0 = 60.0, 90.0, 500.0


def _rotations(rng: np.random.Generator, n: int, joints: int) -> F64:
    """Smooth unit quaternions ``(n, joints, 4)``: each joint turning about its axis."""
    axes = rng.normal(size=(joints, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angle = 0.8 * np.sin(np.arange(n)[:, None] / 9.0 + rng.uniform(0, 6, joints))  # (n, J)
    half = angle[..., None] / 2.0
    return np.concatenate([axes * np.sin(half), np.cos(half)], axis=-1)


def _stream(seed: int, player: str, n: int, rotated: bool) -> list[tuple[float, Pose, bool]]:
    """(arrival, pose, keyframe) of one player, in arrival order."""
    rng = np.random.default_rng(seed)
    joints = 19
    rot = _rotations(rng, n, joints)
    out = []
    seq = 100
    for k in range(n):
        t = T0 + k / POSE_HZ
        pos = np.tile([0.01 * k, 1.0, 0.0], (joints, 1)) + rng.normal(scale=0.01, size=(joints, 3))
        if k >= n // 2:
            pos[:, 0] += 3.0  # a teleport halfway
        keyframe = k == 3 * n // 4  # a rejoin: an older seq, as a keyframe
        seq = 5 if keyframe else seq + 1
        arrive = t + 0.003 + rng.uniform(0.0, 0.040)
        if n // 3 <= k < n // 3 + 12:
            arrive = T0 + (n // 3 + 12) / POSE_HZ + 0.01  # a stall, then a burst
        if rng.random() < 0.2 and not keyframe:
            continue  # dropped
        p = Pose(player, seq, t, pos, rot[k] if rotated else None, keyframe=keyframe)
        out.append((arrive, p, keyframe))
    return sorted(out, key=lambda x: x[0])


@pytest.mark.parametrize(
    "config",
    [InterpConfig(), InterpConfig(adaptive=False), InterpConfig(max_extrapolate_s=0.0, capacity=4)],
    ids=["adaptive", "fixed", "no-extrapolation-small"],
)
def test_batched_frames_match_the_reference(config: InterpConfig) -> None:
    n = 240
    players = [f"p{k}" for k in range(6)]
    arrivals = sorted((
        (a, k, p, kf)
        for k, name in enumerate(players)
        for a, p, kf in _stream(k, name, n, rotated=k != 5)
    ), key=lambda x: (x[0], x[1]))  # fmt: skip
    batched = Interpolator(config)
    single = {name: PoseBuffer(config) for name in players}
    reference = {name: ReferenceBuffer(config) for name in players}
    i = 0
    frames = corrected = 0
    now = T0
    while now < T0 + n / POSE_HZ + 0.3:
        while i < len(arrivals) and arrivals[i][0] <= now:
            _, _, pose, kf = arrivals[i]
            batched.push(pose, keyframe=kf)
            single[pose.player].push(pose, keyframe=kf)
            reference[pose.player].push(pose, keyframe=kf)
            i += 1
        shown = batched.poses_at(now)
        for name in batched.players:  # each queried from its first pose on, as there
            want = reference[name].pose_at(now)
            one = single[name].pose_at(now)
            got = shown.get(name)
            if want is None:
                assert got is None and one is None
                continue
            for pose in (got, one):
                assert pose is not None
                assert (pose.mode, pose.seq, pose.t) == (want.mode, want.seq, want.t)
                np.testing.assert_allclose(pose.positions, want.positions, rtol=0, atol=1e-9)
                if want.rotations is None:
                    assert pose.rotations is None
                else:
                    assert pose.rotations is not None
                    np.testing.assert_allclose(pose.rotations, want.rotations, rtol=0, atol=1e-9)
            frames += 1
            raw = reference[name]._raw(want.t)
            assert raw is not None
            corrected += not np.array_equal(raw.positions, want.positions)
        now += 1.0 / DISPLAY_HZ
    assert frames > 1500
    if config.correction_s > 0:  # the stream makes the corrections this test is for
        assert corrected > 50, corrected


def test_advance_moves_the_delay_as_sampling_does() -> None:
    """A frame that draws nobody (``advance``) shows the same time and moves the
    adaptive delay exactly as a sampled one; the next sample starts afresh."""
    arrivals = _stream(7, "p", 240, rotated=True)
    sampled, advanced = Interpolator(), Interpolator()
    i, now, frames = 0, T0, 0
    while now < T0 + 4.0:
        while i < len(arrivals) and arrivals[i][0] <= now:
            _, pose, kf = arrivals[i]
            sampled.push(pose, keyframe=kf)
            advanced.push(pose, keyframe=kf)
            i += 1
        shown = sampled.poses_at(now)
        taus = advanced.advance(now)
        assert set(taus) == set(shown)
        for player, pose in shown.items():
            assert taus[player] == pose.t
            buf = advanced.buffer(player)
            assert buf is not None and buf.shown_t is None  # nothing was drawn
            frames += 1
        now += 1.0 / DISPLAY_HZ
    assert frames > 300
    one = advanced.buffer("p")
    assert one is not None
    again = one.pose_at(now)
    assert again is not None and again.t == one.shown_t
