"""v2 delta records: the C encoder (``server/native/pc_records.c``) against the numpy
reference, record by record along chains of deltas, and its records read back by the
reference decoder to the state it says the client holds."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.online.protocol import records
from posecast.online.protocol.records import PoseState, Recon

needs_native = pytest.mark.skipif(
    "native" not in records.DELTA_ENCODERS, reason="the C extension is not built"
)

# Per step of a chain: how far the rotations move (radians-ish noise on the quaternion
# components), how far the root moves (0.1 mm) and the seq step. Small steps fit the
# narrow classes, 0.3 and the 2 m root jump do not fit at all, 256 overflows the seq.
_STEPS = [(0.001, 30, 1), (0.01, 300, 2), (0.05, 3000, 1), (0.3, 20000, 1), (0.002, 5, 256)]


def _unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    q = rng.normal(size=(*shape, 4))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _chains(encoder: str, seed: int, players: int = 40, steps: int = 20) -> list[list]:
    """Every step's records of ``players`` avatars from one keyframe on, each delta
    against the reference the previous record left (a keyframe where one does not fit)."""
    rng = np.random.default_rng(seed)
    world = _unit(rng, (players, 19))
    pos = rng.normal(size=(players, 19, 3))
    names = [f"p{i}" for i in range(players)]
    first = PoseState.batch(
        names, [7] * players, 0.0, pos, world, [1.0] * players, [False] * players
    )
    refs: list[Recon] = []
    for s in first:
        assert s is not None
        refs.append(s.keyframe()[1])
    roots = [s.root for s in first if s is not None]
    out = []
    for k in range(steps):
        noise, move, dseq = _STEPS[k % len(_STEPS)]
        world = world + rng.normal(scale=noise, size=world.shape)
        world /= np.linalg.norm(world, axis=-1, keepdims=True)
        roots = [(x + int(rng.integers(-move, move + 1)), y, z) for x, y, z in roots]
        seqs = [r.seq + dseq for r in refs]
        flags = [int(f) for f in rng.integers(0, 3, size=players)]
        got = records.encode_deltas(refs, seqs, roots, world, flags, encoder=encoder)
        out.append(got)
        refs = [r if g is None else g[1] for g, r in zip(got, refs, strict=True)]
    return out


@needs_native
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_native_encoder_matches_the_numpy_reference(seed: int) -> None:
    ref, got = _chains("numpy", seed), _chains("native", seed)
    records_, same, deltas = 0, 0, 0
    for step_ref, step_got in zip(ref, got, strict=True):
        for a, b in zip(step_ref, step_got, strict=True):
            records_ += 1
            assert (a is None) == (b is None)
            if a is None or b is None:
                continue
            deltas += 1
            same += a[0] == b[0]
            ra, rb = a[1], b[1]
            assert (rb.seq, rb.root, rb.step_root) == (ra.seq, ra.root, ra.step_root)
            # The two differ only in the last bits of a float: numpy's arctan2 and its
            # einsum's order of summation are not libm's and C's.
            np.testing.assert_allclose(rb.items, ra.items, rtol=0, atol=1e-12)
            assert (np.abs(rb.step_rot - ra.step_rot) <= 1).all()
    # Both fitting and not fitting occurred, and (float ties aside) the same bytes.
    assert 0 < deltas < records_
    assert same >= 0.999 * deltas, f"{deltas - same} of {deltas} delta records differ"


@needs_native
def test_native_records_decode_to_the_state_they_claim() -> None:
    """The reference decoder, reading the C encoder's records, rebuilds what the C
    encoder says the client holds (the closed loop the deltas rely on)."""
    rng = np.random.default_rng(5)
    world = _unit(rng, (1, 19))
    state = PoseState.batch(["a"], [1], 0.0, np.zeros((1, 19, 3)), world, [1.0], [False])[0]
    assert state is not None
    body, claimed = state.keyframe()
    held: dict[int, Recon | None] = {0: None}
    records.decode_records(records.write_leb128(0) + body, held)
    root = state.root
    for k in range(200):
        world = world + rng.normal(scale=0.01, size=world.shape)
        world /= np.linalg.norm(world, axis=-1, keepdims=True)
        root = (root[0] + 40, root[1] - 3, root[2] + k % 7)
        got = records.encode_deltas([claimed], [k + 2], [root], world, [0], encoder="native")[0]
        assert got is not None
        body, claimed = got
        (rec,) = records.decode_records(records.write_leb128(0) + body, held)
        assert not rec.keyframe and rec.recon.seq == k + 2 and rec.recon.root == root
        np.testing.assert_allclose(rec.recon.items, claimed.items, rtol=0, atol=1e-9)
        assert (rec.recon.step_rot == claimed.step_rot).all()


@needs_native
def test_native_encoder_refuses_arrays_of_the_wrong_shape() -> None:
    from posecast import _native

    m = 2
    args = [
        np.array([*range(-1, 18)], np.int64),  # parents: each joint's the one before
        np.ones(m, np.int64),
        np.zeros(m, np.int64),
        np.zeros(m, np.int64),
        np.zeros((m, 19, 4)),
        np.zeros((m, 19, 3), np.int64),
        np.zeros((m, 19, 4)),
        np.zeros((m, 3), np.int64),
        np.zeros((m, 3), np.int64),
        np.zeros((m, 3), np.int64),
        np.empty((m, 19, 4)),
        np.empty((m, 19, 3), np.int64),
        np.empty((m, records.MAX_DELTA_BYTES), np.uint8),
        np.empty(m, np.int64),
    ]
    _native.encode_deltas(*args)  # the right shapes are taken
    bad = list(args)
    bad[6] = np.zeros((m, 18, 4))
    with pytest.raises(ValueError, match="world"):
        _native.encode_deltas(*bad)
    bad = list(args)
    bad[0] = np.array([-1, 2, *range(1, 18)], np.int64)  # joint 1's parent after it
    with pytest.raises(ValueError, match="parents"):
        _native.encode_deltas(*bad)


def test_the_server_encodes_with_the_first_encoder_that_loads() -> None:
    assert records.DELTA_ENCODERS[0] == records.DELTA_ENCODER
    assert records.DELTA_ENCODERS[-1] == "numpy"
    with pytest.raises(ValueError, match="no delta encoder 'fast'"):
        records.encode_deltas([], [], [], np.zeros((0, 19, 4)), [], encoder="fast")


def test_an_install_without_the_extension_names_only_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """Asked for ``native`` where the C extension did not load: a ValueError naming
    what there is, not an AssertionError from inside the encoder."""
    monkeypatch.setattr(records, "DELTA_ENCODERS", ("numpy",))
    monkeypatch.setattr(records, "_native", None)
    with pytest.raises(ValueError, match="no delta encoder 'native': one of numpy"):
        records.encode_deltas([], [], [], np.zeros((0, 19, 4)), [], encoder="native")


@needs_native
def test_a_rotation_step_without_an_integer_is_no_delta() -> None:
    """A pelvis rotation with an infinite component (a degenerate pose) has a residual
    of no integer steps (NaN): converting that is undefined in C (numpy gives
    INT64_MIN), so the pose makes no delta and the server sends a keyframe instead."""
    rng = np.random.default_rng(9)
    world = _unit(rng, (2, 19))
    states = PoseState.batch(
        ["a", "b"], [1, 1], 0.0, np.zeros((2, 19, 3)), world, [1.0] * 2, [0, 0]
    )
    refs = [s.keyframe()[1] for s in states if s is not None]
    bad = world.copy()
    bad[1, 0] = [np.inf, 0.0, 0.0, 1.0]
    got = records.encode_deltas(refs, [2, 2], [refs[0].root] * 2, bad, [0, 0], encoder="native")
    assert got[0] is not None and got[1] is None
