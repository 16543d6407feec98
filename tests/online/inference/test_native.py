"""The native kernels against a float64 reference, on every ISA level this CPU runs.

The reference (``reference64``) is the decoder graph, FK, contact IK and anomaly
error written out in float64 numpy from the same ONNX weights. Bounds (issue 18):
fp32 levels within 1e-4 in the hidden state after 1 and after 60 recurrent steps;
bf16 within 5 mm p99 in joint positions and at most 0.1 % contact flips.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import warnings
from typing import Any

import numpy as np
import pytest

from posecast.body.batch_fk import fk32
from posecast.body.hinge import ELBOW_LIMBS, FADES, KNEE_LIMBS, hinge_quat, limb_table
from posecast.body.ik import ContactIK
from posecast.body.pelvis import PelvisPoses
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import aa2mat, mat2quat
from posecast.offline.train.masks import TABLE_SETS
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ports import Models, PoolIK
from posecast.online.engine.ring import rest_frame
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine
from posecast.online.inference.onnx_backend import NumpyPool
from posecast.skeleton import Joint, reference_offsets
from posecast.tracking.sites import TrackerSet
from tests.online.inference import reference64 as ref

native = pytest.importorskip("posecast.online.inference.native")
from posecast import _native  # noqa: E402  (built, since the import above did not skip)

LEVELS = native.native_isas()


@pytest.fixture(params=LEVELS)
def level(request: pytest.FixtureRequest) -> object:
    """Each level in its default precision: bf16 gates on ``avx512bf16``, fp32 on the
    others (bf16 on every level: test_native_bf16.py)."""
    before, before_p = native.native_isa(), _native.precision()
    native.set_native_isa(request.param)
    native.set_native_precision("bf16" if request.param == "avx512bf16" else "fp32")
    yield request.param
    native.set_native_isa(before)
    native.set_native_precision(before_p)


def test_the_extension_is_built_where_a_compiler_is() -> None:
    # `pip install -e .` builds it (setup.py, optional); a silent build failure on a
    # machine with a compiler would ship the slow backend unnoticed.
    assert shutil.which("cc") or shutil.which("gcc")
    assert "generic" in LEVELS


def load_decoders(name: str) -> tuple[object, ref.Decoder64]:
    dec, _ = native.load_native(Models(name, "anomaly", None, 2, 10, 0.2))
    return dec, ref.Decoder64.load(name)


def run_decoders(
    dec: object, d64: ref.Decoder64, steps: int, rng: np.random.Generator
) -> dict[str, float]:
    G, N = 5, 40
    R = G * N
    eps = rng.standard_normal((R, d64.latent)).astype(np.float32)
    cache = dec.cache_latents(eps)  # type: ignore[attr-defined]
    h32 = np.zeros((R, d64.hidden), np.float32)
    h64 = np.zeros((R, d64.hidden))
    # raw features around the training distribution (the decoder normalises them)
    mean, std = d64.w["feat.mean"], 1.0 / d64.w["feat.inv_std"]
    base = mean + 0.5 * std * rng.standard_normal((G, d64.n_features))
    worst: dict[str, float] = {}
    for t in range(steps):
        wave = 0.3 * std * np.sin(0.1 * t + np.arange(d64.n_features))
        x = (base + wave).astype(np.float32)
        out = {
            "rotations": np.zeros((R, 108), np.float32),
            "contacts": np.zeros((R, 2), np.float32),
            "h_out": np.zeros((R, d64.hidden), np.float32),
        }
        if d64.n_root:
            out["root"] = np.zeros((R, d64.n_root), np.float32)
        dec.step(x, N, cache, h32, out)  # type: ignore[attr-defined]
        rot64, con64, h64, root64 = d64.step(x.astype(np.float64), N, eps.astype(np.float64), h64)
        h32 = out["h_out"].copy()
        if t in (0, steps - 1):
            key = "first" if t == 0 else "last"
            worst[f"h_{key}"] = float(np.abs(h32 - h64).max())
            worst[f"rot_{key}"] = float(np.abs(out["rotations"] - rot64).max())
            worst[f"con_{key}"] = float(np.abs(out["contacts"] - con64).max())
            if d64.n_root:
                worst[f"root_{key}"] = float(np.abs(out["root"] - root64).max())
            pos32 = ref.fk_positions64(out["rotations"].astype(np.float64))
            pos64 = ref.fk_positions64(rot64)
            worst[f"pos_p99_{key}"] = float(
                np.percentile(np.linalg.norm(pos32 - pos64, axis=-1), 99)
            )
            worst[f"flips_{key}"] = float(np.mean((out["contacts"] > 0.5) != (con64 > 0.5)))
    return worst


@pytest.mark.parametrize("name", ["cvae_decoder", "cvae_decoder_hmd3"])
def test_decoder_matches_float64_after_1_and_60_steps(level: str, name: str) -> None:
    dec, d64 = load_decoders(name)
    w = run_decoders(dec, d64, 60, np.random.default_rng(1))
    if level == "avx512bf16":
        assert w["pos_p99_last"] < 5e-3, w
        assert w["flips_last"] <= 1e-3, w
    else:
        assert w["h_first"] < 1e-4 and w["h_last"] < 1e-4, w
        assert w["rot_last"] < 1e-4 and w["con_last"] < 1e-4, w
        if d64.n_root:
            assert w["root_last"] < 1e-4, w


def _pool_inputs(rng: np.random.Generator, G: int, N: int) -> dict[str, np.ndarray]:
    R = G * N
    mean = np.array(ref.sidecar("cvae_decoder")["mean_pose_rot6d"], np.float32).reshape(1, 108)
    q = rng.standard_normal((G, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {
        "rot": (mean + 0.25 * rng.standard_normal((R, 108))).astype(np.float32),
        "con": rng.uniform(0, 1, (R, 2)).astype(np.float32),
        "root_mat": ref.quat2mat64(q).astype(np.float32),
        "root_pos": np.c_[
            rng.uniform(-2, 2, G), rng.uniform(0.7, 1.0, G), rng.uniform(-2, 2, G)
        ].astype(np.float32),
        "locked": rng.uniform(0, 1, (R, 2)) > 0.5,
        "lock_pos": rng.standard_normal((R, 2, 3)) * 0.3,
        "release": rng.integers(0, 11, (R, 2)).astype(np.int64),
        "suppressed": rng.uniform(0, 1, (R, 2)) > 0.7,
    }


@pytest.mark.parametrize("group", [1, 25])
def test_pool_matches_float64_fk_ik_and_scores(level: str, group: int) -> None:
    _, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 2, 10, 0.2))
    rng = np.random.default_rng(2)
    inp = _pool_inputs(rng, 200 // group, group)
    R = len(inp["rot"])
    ik = PoolIK(*(inp[k].copy() for k in ("locked", "lock_pos", "release", "suppressed")))
    world = np.zeros((R, 19, 3), np.float32)
    pelvis = PelvisPoses(inp["root_mat"], inp["root_pos"], group)
    scores = pool.step(inp["rot"], inp["con"], pelvis, ik, world)
    ik64 = {k: inp[k].copy() for k in ("locked", "lock_pos", "release", "suppressed")}
    world64, scores64 = ref.pool64(
        inp["rot"].astype(np.float64),
        inp["con"].astype(np.float64),
        np.repeat(inp["root_mat"].astype(np.float64), group, 0),
        np.repeat(inp["root_pos"].astype(np.float64), group, 0),
        ik64,
        release_frames=10,
        max_drift_m=0.2,
    )
    assert np.abs(world - world64).max() < 1e-4
    assert np.abs(scores - scores64).max() < 1e-4
    for k in ("locked", "release", "suppressed"):
        assert np.array_equal(getattr(ik, k), ik64[k]), k
    assert np.abs(ik.lock_pos - ik64["lock_pos"]).max() < 1e-5
    # the IK did something: some feet were locked or released and moved
    assert (ik.locked | (ik.release > 0)).mean() > 0.2


def test_emit_matches_the_numpy_display_path(level: str) -> None:
    """The shown pose: FK with rotations, the display IK (thigh and shin swing) and
    quaternions, against batch_fk.fk32 + ContactIK.step(world_mat) + mat2quat."""
    _, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 2, 10, 0.2))
    rng = np.random.default_rng(4)
    inp = _pool_inputs(rng, 300, 1)
    ik = PoolIK(*(inp[k].copy() for k in ("locked", "lock_pos", "release", "suppressed")))
    positions, quats = pool.emit(inp["rot"], inp["con"], inp["root_mat"], inp["root_pos"], ik)
    s = {k: inp[k].copy() for k in ("locked", "lock_pos", "release", "suppressed")}
    wm, wp = fk32(inp["rot"], inp["root_mat"], inp["root_pos"])
    assert wm is not None
    before_m, before_p = wm.copy(), wp.copy()
    ContactIK(s["locked"], s["lock_pos"], s["release"], 10, s["suppressed"], 0.2).step(
        wm, wp, inp["con"]
    )
    q = mat2quat(wm)
    # Both paths ran the knee mirror (ik.two_bone_ik's hint): many moved legs had their
    # knee behind the thigh's forward side of the hip-to-new-ankle line.
    behind = 0
    for thigh, shin, foot in ((11, 12, 13), (15, 16, 17)):
        moved = np.abs(wp[:, foot] - before_p[:, foot]).max(-1) > 1e-6
        u = wp[:, foot] - before_p[:, thigh]
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        bend = before_p[:, shin] - before_p[:, thigh]
        fwd = before_m[:, thigh, :, 2]
        off = bend - np.sum(bend * u, -1, keepdims=True) * u
        h = fwd - np.sum(fwd * u, -1, keepdims=True) * u
        behind += int((moved & (np.sum(off * h, -1) < 0)).sum())
    assert behind > 50
    assert np.abs(positions - wp).max() < 1e-4  # 0.1 mm (float32 FK, float64 IK)
    # q and -q are one rotation; mat2quat keeps w >= 0, so compare up to sign
    dq = np.minimum(np.abs(quats - q).max(-1), np.abs(quats + q).max(-1))
    assert dq.max() < 1e-4
    for k in ("locked", "release", "suppressed"):
        assert np.array_equal(getattr(ik, k), s[k]), k
    assert (s["locked"] | (s["release"] > 0)).mean() > 0.2  # the IK moved legs


def test_threads_do_not_change_results(level: str) -> None:
    dec, _ = native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
    rng = np.random.default_rng(3)
    R = 1000
    x = rng.standard_normal((10, 24)).astype(np.float32)
    cache = dec.cache_latents(rng.standard_normal((R, 30)).astype(np.float32))
    h = (0.5 * rng.standard_normal((R, 128))).astype(np.float32)
    outs = []
    for threads in (1, 2):
        native.load_native(Models("cvae_decoder", "anomaly", None, threads, 10, 0.2))
        o = {k: np.zeros((R, n), np.float32) for k, n in (("rotations", 108), ("contacts", 2))}
        o["h_out"] = np.zeros((R, 128), np.float32)
        dec.step(x, 100, cache, h, o)
        outs.append(o)
    for k in outs[0]:
        assert np.array_equal(outs[0][k], outs[1][k]), k


def test_bad_buffers_raise_value_errors_not_crashes() -> None:
    dec, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
    R = 10
    good = {
        "rotations": np.zeros((R, 108), np.float32),
        "contacts": np.zeros((R, 2), np.float32),
        "h_out": np.zeros((R, 128), np.float32),
    }
    x = np.zeros((1, 24), np.float32)
    cache, h = np.zeros((R, 128), np.float32), np.zeros((R, 128), np.float32)
    with pytest.raises(ValueError, match="expected"):
        dec.step(x, 10, cache[:5], h, good)  # too few cache rows
    with pytest.raises(ValueError, match="dtype"):
        dec.step(x, 10, cache, h, {**good, "contacts": np.zeros((R, 2), np.float64)})
    with pytest.raises(ValueError, match="writable"):
        ro = np.zeros((R, 128), np.float32)
        ro.flags.writeable = False
        dec.step(x, 10, cache, h, {**good, "h_out": ro})
    ik = PoolIK(
        np.zeros((R, 2), bool),
        np.zeros((R, 2, 3)),
        np.zeros((R, 2), np.int64),
        np.zeros((R, 2), bool),
    )
    rm, rp = np.zeros((1, 3, 3), np.float32), np.zeros((1, 3), np.float32)
    with pytest.raises(ValueError, match="multiple of group"):
        pool.step(
            good["rotations"],
            good["contacts"],
            PelvisPoses(rm, rp, 3),
            ik,
            np.zeros((R, 19, 3), np.float32),
        )
    bad_ik = PoolIK(ik.locked, ik.lock_pos.astype(np.float32), ik.release, ik.suppressed)
    with pytest.raises(ValueError, match="lock_pos"):
        pool.step(
            good["rotations"],
            good["contacts"],
            PelvisPoses(rm, rp, 10),
            bad_ik,
            np.zeros((R, 19, 3), np.float32),
        )


def _isa_in_subprocess(value: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "POSECAST_NATIVE_ISA": value}
    code = "from posecast import _native; print(_native.isa())"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)


def test_posecast_native_isa_caps_the_level() -> None:
    for lv in LEVELS:
        r = _isa_in_subprocess(lv)
        assert r.returncode == 0 and r.stdout.strip() == lv, r.stderr
    r = _isa_in_subprocess("sse9")
    assert r.returncode != 0 and "POSECAST_NATIVE_ISA=sse9" in r.stderr


def test_a_level_that_disagrees_with_generic_is_dropped(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    if LEVELS[0] == "generic":
        pytest.skip("only the generic level runs here")
    before = native.native_isa()
    real = native._probe

    def probe(dec: object, pool: object, level: str) -> list[np.ndarray]:
        out = real(dec, pool, level)
        return [a + 1.0 for a in out] if level == LEVELS[0] else out

    monkeypatch.setattr(native, "_probe", probe)
    monkeypatch.setattr(native, "_checked", set())
    native.set_native_isa(LEVELS[0])
    try:
        with caplog.at_level("WARNING", logger="posecast.engine"):
            native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
        assert native.native_isa() == LEVELS[1]
        assert f"level {LEVELS[0]} disagrees with generic" in caplog.text
    finally:
        native.set_native_isa(before)


def test_a_bf16_level_that_disagrees_drops_to_the_next_in_fp32(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Not to the emulation of bf16 on the next level, which is slower than fp32."""
    if "avx512bf16" not in native.native_isas():
        pytest.skip("needs avx512_bf16: this CPU's levels are " + ", ".join(LEVELS))
    before, precision = native.native_isa(), _native.precision()
    real = native._probe

    def probe(dec: object, pool: object, level: str) -> list[np.ndarray]:
        out = real(dec, pool, level)
        return [a + 1.0 for a in out] if level == "avx512bf16" else out

    monkeypatch.setattr(native, "_probe", probe)
    monkeypatch.setattr(native, "_checked", set())
    native.set_native_isa("avx512bf16")
    native.set_native_precision("bf16")
    try:
        with caplog.at_level("WARNING", logger="posecast.engine"):
            native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
        assert native.native_isa() == "avx512f" and native.native_precision() == "fp32"
    finally:
        native.set_native_isa(before)
        native.set_native_precision(precision)


def test_a_forked_child_runs_the_kernels_on_new_workers() -> None:
    """After fork the child has only the forking thread: the pool must start workers
    again instead of waiting for the parent's (which would hang the child)."""
    dec, _ = native.load_native(Models("cvae_decoder", "anomaly", None, 2, 10, 0.2))
    R = 500
    rng = np.random.default_rng(6)
    x = rng.standard_normal((5, 24)).astype(np.float32)
    cache = dec.cache_latents(rng.standard_normal((R, 30)).astype(np.float32))
    h = np.zeros((R, 128), np.float32)

    def run() -> np.ndarray:
        o = {k: np.zeros((R, n), np.float32) for k, n in (("rotations", 108), ("contacts", 2))}
        o["h_out"] = np.zeros((R, 128), np.float32)
        dec.step(x, 100, cache, h, o)
        return o["h_out"]

    want = run()
    read, write = os.pipe()
    with warnings.catch_warnings():  # 3.12+ warns about fork with threads running
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:  # the child: one call, then report whether it matched
        try:
            os.write(write, b"1" if np.array_equal(run(), want) else b"0")
        finally:
            os._exit(0)
    os.close(write)
    got = os.read(read, 1)
    _, status = os.waitpid(pid, 0)
    assert got == b"1" and status == 0


def _upper_inputs(E: int, seed: int) -> dict[str, np.ndarray]:
    """Shown poses and trackers for the upper-body pass: trackers near their joints,
    far beyond reach, or exactly on them; some hints on the shoulder-target line (the
    two-bone solve's fallbacks), some headsets on the head (no swing)."""
    rng = np.random.default_rng(seed)
    local = aa2mat(rng.normal(0.0, 0.4, (E, 19, 3)))
    root = np.array([0.0, 1.0, 0.0]) + rng.normal(0.0, 0.3, (E, 3))
    wm, wp = fk_mat(local, root, reference_offsets())
    tp = wp[:, [Joint.HEAD, Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.PELVIS]].copy()
    scale = rng.choice([0.0, 0.03, 0.2, 1.5], (E, 1, 1))
    tp += scale * rng.normal(0.0, 1.0, tp.shape)
    # A left hand straight out along its arm's line: the elbow hint on that line.
    straight = rng.random(E) < 0.1
    sh = wp[straight, Joint.LEFT_UPPER_ARM]
    tp[straight, 1] = sh + 2.0 * (wp[straight, Joint.LEFT_FOREARM] - sh)
    return {
        "pos": wp.astype(np.float32),
        "quat": mat2quat(wm).astype(np.float32),
        "tp": tp,
        "tq": mat2quat(aa2mat(rng.normal(0.0, 1.0, (E, 4, 3)))),
        "free": rng.random(E) < 0.5,
    }


@pytest.mark.parametrize("wrist_share", [0.0, 0.75, 1.0])
@pytest.mark.parametrize("free", [False, True])
@pytest.mark.parametrize("rows", [3, 4, 10])
def test_upper_body_matches_the_numpy_reference(wrist_share: float, free: bool, rows: int) -> None:
    """The C port of the upper-body pass (pc_upper.c) against upper_ik.solve_upper_body,
    the numpy reference, on 1,000 poses: every position, rotation and reach flag, with
    the tracker rows of ``hmd3`` (3), the waist layout (4) and a tracker set (10)."""
    _, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
    ref_pool = NumpyPool.__new__(NumpyPool)  # its upper_body needs no scorer
    inp = _upper_inputs(1000, seed=11)
    roots = inp["free"] if free else None
    tp, tq = _tracker_rows(inp["tp"], rows), _tracker_rows(inp["tq"], rows)
    args = (inp["pos"], inp["quat"], tp, tq, roots, wrist_share)
    pos, quat, limited = pool.upper_body(*args)
    want_pos, want_quat, want_limited = ref_pool.upper_body(*args)
    assert 0.1 < want_limited.mean() < 0.95  # both reached and out-of-reach rows
    np.testing.assert_array_equal(limited, want_limited)
    assert np.abs(pos - want_pos).max() < 1e-6
    dq = np.minimum(np.abs(quat - want_quat).max(-1), np.abs(quat + want_quat).max(-1))
    assert dq.max() < 1e-6
    assert pos.dtype == np.float32 and quat.dtype == np.float32


def _tracker_rows(a: np.ndarray, rows: int) -> np.ndarray:
    """``a (E, 4, k)`` cut or padded (with other values) to ``rows`` tracker rows."""
    if rows <= a.shape[1]:
        return np.ascontiguousarray(a[:, :rows])
    extra = np.random.default_rng(rows).normal(0.0, 1.0, (len(a), rows - a.shape[1], a.shape[2]))
    return np.concatenate([a, extra], axis=1)


def test_the_passes_in_c_take_no_poses_and_in_place_outputs() -> None:
    _, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
    inp = _upper_inputs(0, seed=2)
    pos, quat, limited = pool.upper_body(inp["pos"], inp["quat"], inp["tp"], inp["tq"], None, 0.5)
    assert pos.shape == (0, 19, 3) and quat.shape == (0, 19, 4) and limited.shape == (0,)
    pool.hinge(inp["pos"], inp["quat"], KNEE_LIMBS)


def test_hinge_bad_buffers_and_limbs_raise_value_errors() -> None:
    inp = _upper_inputs(4, seed=1)
    pos, quat = inp["pos"], inp["quat"].copy()
    table = limb_table(KNEE_LIMBS)

    def hinge(positions: np.ndarray, rotations: np.ndarray, limbs: np.ndarray) -> None:
        _native.hinge(positions, rotations, limbs, *FADES)

    read_only = quat.copy()
    read_only.flags.writeable = False
    for bad, match in (
        (read_only, "writable"),
        (quat.astype(np.float64), "dtype"),
        (np.asfortranarray(quat), "C-contiguous"),
    ):
        with pytest.raises(ValueError, match=match):
            hinge(pos, bad, table)
    for joint in (np.nan, 19.0, -1.0, 2.5):
        odd = table.copy()
        odd[1, 0] = joint
        with pytest.raises(ValueError, match="outside"):
            hinge(pos, quat, odd)
    shared = np.concatenate([table, table[:1]])  # the left knee twice
    with pytest.raises(ValueError, match="two limbs"):
        hinge(pos, quat, shared)
    with pytest.raises(ValueError, match="at most"):
        hinge(pos, quat, np.zeros((9, 9)))
    np.testing.assert_array_equal(quat, inp["quat"])  # nothing written on an error


def test_upper_body_bad_buffers_raise_value_errors() -> None:
    _, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
    inp = _upper_inputs(4, seed=1)
    with pytest.raises(ValueError, match="tracker_pos"):
        pool.upper_body(inp["pos"], inp["quat"], inp["tp"][:, :2], inp["tq"], None, 0.5)
    with pytest.raises(ValueError, match="rotations"):
        pool.upper_body(inp["pos"], inp["quat"][:2], inp["tp"], inp["tq"], None, 0.5)
    with pytest.raises(ValueError, match="free_root"):
        pool.upper_body(inp["pos"], inp["quat"], inp["tp"], inp["tq"], inp["free"][:2], 0.5)


@pytest.mark.parametrize("limbs", ["knees", "elbows"])
def test_hinge_matches_the_numpy_reference(limbs: str) -> None:
    """The C port of the hinges against hinge.hinge_quat on 2,000 random poses: limbs
    bent every way (forward, backward past the fade, nearly straight)."""
    _, pool = native.load_native(Models("cvae_decoder", "anomaly", None, 1, 10, 0.2))
    table = KNEE_LIMBS if limbs == "knees" else ELBOW_LIMBS
    rng = np.random.default_rng(5)
    local = aa2mat(rng.normal(0.0, 0.8, (2000, 19, 3)))
    straight = [Joint.LEFT_SHIN, Joint.RIGHT_SHIN, Joint.LEFT_FOREARM, Joint.RIGHT_FOREARM]
    local[:100, straight] = np.eye(3)
    wm, wp = fk_mat(local, rng.normal(0.0, 1.0, (2000, 3)), reference_offsets())
    pos, quat = wp.astype(np.float32), mat2quat(wm).astype(np.float32)
    got, want = quat.copy(), quat.copy()
    pool.hinge(pos, got, table)
    hinge_quat(pos, want, table)
    moved = (np.abs(want - quat).max(-1) > 1e-4).any(-1)
    assert moved.mean() > 0.5  # the reference turned most poses' limbs
    dq = np.minimum(np.abs(got - want).max(-1), np.abs(got + want).max(-1))
    assert dq.max() < 1e-6


class _NumpyPasses:
    """The native pool with the shown pose's passes as the numpy references."""

    def __init__(self, pool: Any) -> None:
        self.pool, self.threshold_m = pool, pool.threshold_m
        self.step, self.emit = pool.step, pool.emit

    def upper_body(self, *args: Any) -> Any:
        return NumpyPool.upper_body(*args)

    def hinge(self, *args: Any) -> None:
        NumpyPool.hinge(self, *args)  # type: ignore[arg-type]


@pytest.mark.parametrize("layout", ["hmd3+waist", "hmd3", "sites"])
def test_the_engine_streams_the_same_poses_with_the_passes_in_c_or_numpy(layout: str) -> None:
    """Two native engines, the passes in C and in numpy, on a walk of 40 frames (sites:
    3, 4, 6 and 8 points and 3 + 2 IMUs in one batch): the same poses, rotations and
    reach flags."""
    names = ("3p", "4p", "6p", "8p", "3p+2i") if layout == "sites" else ("a", "b")
    runs = []
    for numpy_passes in (False, True):
        e = load_engine(EngineConfig(samples=8), None, 1, layout, "native")
        if numpy_passes:
            e.pool = _NumpyPasses(e.pool)
        for i, n in enumerate(names):
            e.add_player(
                n,
                seed=i,
                tracker_set=TrackerSet.parse(TABLE_SETS[n]) if layout == "sites" else None,
            )
        rows = e.layout.rows
        out = []
        for t in range(40):
            for i, n in enumerate(names):
                rest = rest_frame(rows)
                pos = rest.pos.copy()
                pos[:, 0] += 2.0 * i + 0.05 * np.sin(0.3 * t + i)
                pos[:, 2] += 0.01 * t
                pos[1:3, 1] += 0.2 * np.sin(0.2 * t)  # the hands move
                e.push(n, TrackerFrame(t, pos, rest.quat))
            out += [(p.positions, p.rotations, p.reach_limited) for p in e.tick().poses]
        runs.append(out)
    assert len(runs[0]) == len(runs[1]) > 20 * len(names)
    for (p, r, lim), (p2, r2, lim2) in zip(*runs, strict=True):
        assert np.abs(p - p2).max() < 1e-5 and lim == lim2
        assert np.minimum(np.abs(r - r2).max(-1), np.abs(r + r2).max(-1)).max() < 1e-5
