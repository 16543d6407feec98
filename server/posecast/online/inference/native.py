"""The ``native`` backend: the C kernels of ``posecast._native`` behind the engine's protocol.

The weights come from the same ONNX files the ``onnx`` backend runs (read with the
``onnx`` package, the format's own reader); nothing else is shipped. The decoder's
first layer is split as the graph splits it: the latent part ``eps @ wz`` is the
per-row latent cache (computed once when a player joins), the tracker part is
computed once per player per frame inside :func:`posecast._native.decode`.

Instruction-set level: the best this CPU runs (``avx512bf16``, ``avx512f``, ``avx2``,
``generic``), capped by ``POSECAST_NATIVE_ISA``; :func:`native_isa` says which.
Precision, a setting of its own: the GRU gates in bf16 (inputs and weights rounded to
bf16, products accumulated in fp32; every other product fp32) by default on the
``avx512bf16`` level, fp32 on the others; ``POSECAST_NATIVE_PRECISION=fp32|bf16``
chooses. bf16 on a level without the instructions is the same arithmetic in plain
vector code (``bf16-emulated``: slower than fp32, for checks, not for serving). Its
validation figures: docs/engine.md, "Precision". Before a level above ``generic`` is
first used, :func:`load_native` checks it against ``generic`` (in the same precision)
on one small batch and steps down a level if they disagree.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from posecast.body.hinge import FADES, Limbs, limb_table
from posecast.body.pelvis import PelvisPoses
from posecast.body.upper_ik import (
    LEAN_SHARE,
    NECK_SHARE,
    REACH_TOLERANCE_M,
    SPINE_REACH_M,
)
from posecast.errors import ModelError
from posecast.online.engine.ports import Models, PoolIK
from posecast.online.inference.artifact import read_sidecar
from posecast.skeleton import PARENTS, reference_offsets

try:
    from posecast import _native
except ImportError as exc:  # not built (no compiler at install time) or not loadable
    raise ImportError(f"posecast._native is not available: {exc}") from exc

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

_NATIVE_PARENTS = (-1, 0, 1, 2, 3, 2, 5, 6, 2, 8, 9, 0, 11, 12, 13, 0, 15, 16, 17)
# The reference bones, for the upper-body pass.
_OFFSETS = np.ascontiguousarray(reference_offsets(), dtype=np.float64)


def native_isa() -> str:
    """The instruction-set level the kernels run on."""
    level: str = _native.isa()
    return level


def native_isas() -> tuple[str, ...]:
    """The levels this CPU can run, best first (``generic`` always)."""
    levels: tuple[str, ...] = _native.isas()
    return levels


PRECISIONS = ("fp32", "bf16")


def native_precision() -> str:
    """The GRU gates' arithmetic as it runs: ``fp32``, ``bf16`` (the level's bf16
    instructions) or ``bf16-emulated`` (the same arithmetic without them)."""
    p: str = _native.precision()
    if p == "bf16" and native_isa() != "avx512bf16":
        return "bf16-emulated"
    return p


def set_native_precision(precision: str) -> None:
    """``fp32`` or ``bf16`` gates, on whatever level runs."""
    _native.set_precision(precision)


def set_native_isa(level: str) -> None:
    """Run on ``level`` (one of :func:`native_isas`); tests use it to cover every level."""
    _native.set_isa(level)


def _initializers(path: Path) -> dict[str, F32]:
    import onnx
    from onnx import numpy_helper

    try:
        model = onnx.load(str(path))
    except Exception as exc:  # onnx raises protobuf's own error types
        raise ModelError(f"cannot read ONNX weights: {exc}", path=path) from exc
    return {
        i.name: np.ascontiguousarray(numpy_helper.to_array(i), dtype=np.float32)
        for i in model.graph.initializer
    }


def _need(w: Mapping[str, F32], name: str, shape: tuple[int, ...], path: Path) -> F32:
    if name not in w:
        raise ModelError(f"the native backend needs weight {name!r}", path=path)
    arr = w[name]
    if arr.shape != shape:
        raise ModelError(f"weight {name!r} is {arr.shape}, expected {shape}", path=path)
    return arr


class NativeDecoder:
    """The decoder step of one artifact, fused in C (see pc_impl.h ``decode_tile``)."""

    def __init__(self, name: str, meta: dict[str, Any], path: Path) -> None:
        self.name, self.meta = name, meta
        mc = meta["model_config"]
        self.latent, self.hidden = int(mc["latent"]), int(mc["hidden"])
        n_root = int(mc.get("root_outputs", 0))
        w = _initializers(path)
        F = len(meta["feature_layout"])
        H, L = self.hidden, self.latent
        self._wz = _need(w, "decoder.fc.wz_t", (L, H), path)
        if n_root:
            pose = np.concatenate(
                [
                    _need(w, "decoder.pose.weight_t_0_108", (H, 108), path),
                    _need(w, f"decoder.pose.weight_t_108_{108 + n_root}", (H, n_root), path),
                ],
                axis=1,
            )
            pose_b = np.concatenate(
                [
                    _need(w, "decoder.pose.bias_0_108", (108,), path),
                    _need(w, f"decoder.pose.bias_108_{108 + n_root}", (n_root,), path),
                ]
            )
        else:
            # torch.onnx names the pose head's initializers by the slice the graph takes
            # of them (``_0_108``) or, when it folds the slice away, plainly.
            sliced = "decoder.pose.weight_t" not in w
            pose = _need(w, "decoder.pose.weight_t" + ("_0_108" if sliced else ""), (H, 108), path)
            pose_b = _need(w, "decoder.pose.bias" + ("_0_108" if sliced else ""), (108,), path)
        head = np.ascontiguousarray(
            np.concatenate([pose, _need(w, "decoder.contact.weight_t", (H, 2), path)], axis=1)
        )
        head_b = np.ascontiguousarray(
            np.concatenate([pose_b, _need(w, "decoder.contact.bias", (2,), path)])
        )
        self.n_root = n_root
        try:
            self._packed = _native.pack_decoder(
                F,
                H,
                108,
                n_root,
                _need(w, "feat.mean", (F,), path),
                _need(w, "feat.inv_std", (F,), path),
                _need(w, "decoder.fc.wx_t", (F, H), path),
                _need(w, "decoder.fc.bias", (H,), path),
                _need(w, "decoder.gru.w_ih_t", (H, 3 * H), path),
                _need(w, "decoder.gru.b_ih", (3 * H,), path),
                _need(w, "decoder.gru.w_hh_t", (H, 3 * H), path),
                _need(w, "decoder.gru.b_hh", (3 * H,), path),
                head,
                head_b,
                True,
            )
        except ValueError as exc:
            raise ModelError(
                f"the native backend cannot run this decoder: {exc}", path=path
            ) from exc
        self.cache_width = H

    def cache_latents(self, eps: F32) -> F32:
        out: F32 = np.ascontiguousarray(np.asarray(eps, np.float32) @ self._wz, dtype=np.float32)
        return out

    def step(self, features: F32, group: int, cache: F32, h: F32, out: Mapping[str, F32]) -> None:
        _native.decode(
            self._packed,
            np.ascontiguousarray(features, dtype=np.float32),
            group,
            np.ascontiguousarray(cache, dtype=np.float32),
            np.ascontiguousarray(h, dtype=np.float32),
            out["rotations"],
            out.get("root"),
            out["contacts"],
            out["h_out"],
        )


class NativePool:
    """FK, contact IK and anomaly error of every candidate row, and the upper-body pass, in C."""

    def __init__(
        self,
        meta: dict[str, Any],
        path: Path,
        release_frames: int,
        max_drift_m: float | None,
    ) -> None:
        if tuple(PARENTS) != _NATIVE_PARENTS:
            raise ModelError("the native kernels were built for another skeleton", path=path)
        self.meta = meta
        self.threshold_m = float(meta.get("implausible_threshold_m", float("nan")))
        w = _initializers(path)
        layers = []
        k = 57
        for i in range(7):
            wt = w.get(f"layers.{i}.weight_t")
            if wt is None or wt.ndim != 2 or wt.shape[0] != k:
                raise ModelError(
                    f"the native backend needs AE layer {i} with {k} inputs", path=path
                )
            n = int(wt.shape[1])
            layers.append((k, n, wt, _need(w, f"layers.{i}.bias", (n,), path)))
            k = n
        try:
            self._packed = _native.pack_pool(
                np.ascontiguousarray(reference_offsets(), dtype=np.float32),
                _need(w, "pose.mean", (57,), path),
                _need(w, "pose.inv_std", (57,), path),
                layers,
            )
        except ValueError as exc:
            raise ModelError(
                f"the native backend cannot run this scorer: {exc}", path=path
            ) from exc
        self.release_frames = int(release_frames)
        self.max_drift = -1.0 if max_drift_m is None else float(max_drift_m)

    def _ik(self, ik: PoolIK) -> tuple[Any, Any, Any, Any, int, float]:
        """The display IK's state (the kernels step it in place) and this pool's settings
        for it, in the order ``pool`` and ``emit`` take them."""
        return (
            ik.locked,
            ik.lock_pos,
            ik.release,
            ik.suppressed,
            self.release_frames,
            self.max_drift,
        )

    def step(
        self, rotations: F32, contacts: F32, pelvis: PelvisPoses, ik: PoolIK, world_out: F32
    ) -> F64:
        scores = np.empty(len(rotations), np.float64)
        _native.pool(
            self._packed,
            rotations,
            contacts,
            *_f32(pelvis.mats, pelvis.places),
            pelvis.group,
            *self._ik(ik),
            world_out,
            scores,
        )
        return scores

    def emit(
        self, rotations: F32, contacts: F32, root_mat: F32, root_pos: F32, ik: PoolIK
    ) -> tuple[F32, F32]:
        """The shown poses of ``E`` rows: world positions ``(E, 19, 3)`` and rotations
        ``(E, 19, 4)`` xyzw after the display IK (``ik`` steps in place)."""
        E = len(rotations)
        positions = np.empty((E, 19, 3), np.float32)
        quats = np.empty((E, 19, 4), np.float32)
        _native.emit(
            self._packed,
            *_f32(rotations, contacts),
            *_f32(root_mat, root_pos),
            *self._ik(ik),
            positions,
            quats,
        )
        return positions, quats

    def upper_body(
        self,
        positions: F32,
        rotations: F32,
        tracker_pos: F64,
        tracker_quat: F64,
        free_root: NDArray[np.bool_] | None,
        wrist_share: float,
    ) -> tuple[F32, F32, NDArray[np.bool_]]:
        """:func:`~posecast.body.upper_ik.solve_upper_body` in C (``pc_upper.c``,
        one pose at a time in double precision; the same figures to float32's last bit
        on the parity tests, at a few microseconds a pose against the reference's
        2-3 ms of numpy call overhead a tick)."""
        E = len(positions)
        pos_out = np.empty((E, 19, 3), np.float32)
        quat_out = np.empty((E, 19, 4), np.float32)
        limited = np.empty(E, np.bool_)
        _native.upper_body(
            np.ascontiguousarray(positions, dtype=np.float32),
            np.ascontiguousarray(rotations, dtype=np.float32),
            np.ascontiguousarray(tracker_pos, dtype=np.float64),
            np.ascontiguousarray(tracker_quat, dtype=np.float64),
            None if free_root is None else np.ascontiguousarray(free_root, dtype=np.bool_),
            float(wrist_share),
            LEAN_SHARE,
            NECK_SHARE,
            SPINE_REACH_M,
            REACH_TOLERANCE_M,
            _OFFSETS,
            pos_out,
            quat_out,
            limited,
        )
        return pos_out, quat_out, limited

    def hinge(self, positions: F32, rotations: F32, limbs: Limbs) -> None:
        """:func:`~posecast.body.hinge.hinge_quat` in C (``pc_upper.c``), in place."""
        pos = np.ascontiguousarray(positions, dtype=np.float32)
        _native.hinge(pos, rotations, limb_table(limbs), *FADES)


_checked: set[str] = set()


def _f32(a: F32, b: F32) -> tuple[F32, F32]:
    """Two arrays as the kernels take them: C-contiguous float32 (no copy where one is)."""
    return np.ascontiguousarray(a, dtype=np.float32), np.ascontiguousarray(b, dtype=np.float32)


def _self_check(dec: NativeDecoder, pool: NativePool) -> None:
    """Before the first use of a level above ``generic``: run one small batch on it
    and on ``generic`` and drop to the next level if they disagree (a level this
    project's machine cannot run is checked on the machine that runs it). A bf16
    level that disagrees drops to the next level in fp32, not to the emulation."""
    import logging

    log = logging.getLogger("posecast.engine")
    levels = list(native_isas())
    while True:
        level = native_isa()
        key = f"{level}/{_native.precision()}"  # each level in each precision once
        if level == "generic" or key in _checked:
            return
        got = _probe(dec, pool, level)
        ref = _probe(dec, pool, "generic")
        # bf16 against generic's bf16: the same products and order of accumulation,
        # but the instruction may round inside a pair differently (docs/engine.md)
        tol = 1e-3 if _native.precision() == "bf16" else 1e-4
        worst = max(float(np.abs(a - b).max()) for a, b in zip(got, ref, strict=True))
        if worst <= tol:
            _checked.add(key)
            set_native_isa(level)
            return
        lower = levels[levels.index(level) + 1]
        if level == "avx512bf16" and _native.precision() == "bf16":
            # bf16 came with the level; below it, it would run emulated (slower than
            # fp32): the next level in its own precision instead
            set_native_precision("fp32")
        log.warning(
            "native kernels: level %s disagrees with generic by %.3g; using %s, precision %s",
            level, worst, lower, _native.precision(),
        )  # fmt: skip
        set_native_isa(lower)


def _probe(dec: NativeDecoder, pool: NativePool, level: str) -> list[F32 | F64]:
    set_native_isa(level)
    rng = np.random.default_rng(0)
    G, N = 3, 37  # rows that fill neither a tile nor a register block
    R = G * N
    F = len(dec.meta["feature_layout"])
    x = rng.standard_normal((G, F)).astype(np.float32) * 0.1
    cache = dec.cache_latents(rng.standard_normal((R, dec.latent)).astype(np.float32))
    h = rng.standard_normal((R, dec.hidden)).astype(np.float32) * 0.5
    out = {
        "rotations": np.zeros((R, 108), np.float32),
        "contacts": np.zeros((R, 2), np.float32),
        "h_out": np.zeros((R, dec.hidden), np.float32),
    }
    if dec.n_root:
        out["root"] = np.zeros((R, dec.n_root), np.float32)
    dec.step(x, N, cache, h, out)
    eye = np.tile(np.eye(3, dtype=np.float32), (G, 1, 1))
    root = np.tile(np.array([0.0, 0.9, 0.0], np.float32), (G, 1))
    ik = PoolIK(
        np.zeros((R, 2), np.bool_),
        np.zeros((R, 2, 3)),
        np.zeros((R, 2), np.int64),
        np.zeros((R, 2), np.bool_),
    )
    world = np.zeros((R, 19, 3), np.float32)
    scores = pool.step(out["rotations"], out["contacts"], PelvisPoses(eye, root, N), ik, world)
    return [*out.values(), world, scores]


def load_native(m: Models) -> tuple[NativeDecoder, NativePool]:
    """The native decoder and pool on the artifacts ``m`` names."""
    _native.set_threads(max(1, int(m.threads)))
    folder = None if m.models_dir is None else str(m.models_dir)
    meta, path = read_sidecar(m.decoder, folder)
    ae_meta, ae_path = read_sidecar(m.anomaly, folder)
    dec = NativeDecoder(m.decoder, meta, path)
    pool = NativePool(ae_meta, ae_path, m.release_frames, m.max_drift_m)
    _self_check(dec, pool)
    return dec, pool
