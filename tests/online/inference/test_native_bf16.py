"""The native kernels' bf16 precision (the GRU gates' inputs and weights rounded to
bf16, products accumulated in fp32).

Every level runs it: ``avx512bf16`` on the vdpbf16ps instruction, the others in plain
vector code that does the instruction's arithmetic (``bf16-emulated``). Checked here:
the emulation against a numpy reference of the same arithmetic (to float32 rounding,
every level this CPU runs), the 60-step bounds of issue 18 against float64, the
hardware against the emulation where the CPU has ``avx512_bf16`` (skipped, saying
which flags it has, where not), and the default: bf16 on the ``avx512bf16`` level,
fp32 on every other, ``POSECAST_NATIVE_PRECISION`` over both.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from posecast.online.engine.ports import Models
from tests.online.inference import reference64 as ref

native = pytest.importorskip("posecast.online.inference.native")

LEVELS = native.native_isas()
F32 = NDArray[np.float32]


def _cpu_flags() -> str:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "no /proc/cpuinfo"
    wanted = ("avx2", "fma", "avx512f", "avx512_bf16")
    line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
    have = [f for f in wanted if f in line.split()]
    return " ".join(have) or "none of " + " ".join(wanted)


NEEDS_BF16 = pytest.mark.skipif(
    "avx512bf16" not in LEVELS,
    reason=f"needs avx512_bf16: this CPU has {_cpu_flags()}",
)


@pytest.fixture
def precision() -> Iterator[None]:
    before_isa, before = native.native_isa(), native.native_precision()
    yield
    native.set_native_isa(before_isa)
    native.set_native_precision("bf16" if before.startswith("bf16") else "fp32")


def bf16(x: NDArray[np.floating]) -> F32:
    """Round float32 to bf16 (kept in float32) as vcvtne2ps2bf16 does: to nearest even,
    denormals to zero (the test data has no inf or NaN)."""
    u = np.ascontiguousarray(x, dtype=np.float32).view(np.uint32)
    r = (u + np.uint32(0x7FFF) + ((u >> np.uint32(16)) & np.uint32(1))) & np.uint32(0xFFFF0000)
    r = np.where((u & np.uint32(0x7F800000)) == 0, u & np.uint32(0x80000000), r)
    out: F32 = r.astype(np.uint32).view(np.float32)
    return out


def gemm_bf16(a: F32, w: F32, bias: F32) -> F32:
    """``a @ w + bias`` as vdpbf16ps computes it from the bias up: per pair of inputs,
    the odd product then the even one, each sum rounded to float32 (a product of two
    bf16 values is exact in float32)."""
    a, w = bf16(a), bf16(w)
    acc = np.broadcast_to(bias, (len(a), len(bias))).astype(np.float32)
    for k in range(0, a.shape[1], 2):
        acc = acc + a[:, k + 1, None] * w[k + 1]
        acc = acc + a[:, k, None] * w[k]
    return acc


def _sigmoid(x: NDArray[np.float64]) -> NDArray[np.float64]:
    out: NDArray[np.float64] = 1.0 / (1.0 + np.exp(-x))
    return out


def step_bf16(d64: ref.Decoder64, cache: F32, h: F32) -> tuple[F32, NDArray[np.float64]]:
    """One decoder step with the tracker features at their mean (so the first layer is
    ``bias + cache``, one float32 add, exact in both): the gates' products in bf16 as
    above, the rest in float64. Returns the gates' pre-activations and the new state."""
    w, H = d64.w, d64.hidden
    f = np.maximum(w["decoder.fc.bias"].astype(np.float32) + cache, np.float32(0))
    gi = gemm_bf16(f, w["decoder.gru.w_ih_t"], w["decoder.gru.b_ih"].astype(np.float32))
    gh = gemm_bf16(h, w["decoder.gru.w_hh_t"], w["decoder.gru.b_hh"].astype(np.float32))
    g, hh = gi.astype(np.float64), gh.astype(np.float64)
    r = _sigmoid(g[:, :H] + hh[:, :H])
    u = _sigmoid(g[:, H : 2 * H] + hh[:, H : 2 * H])
    n = np.tanh(g[:, 2 * H :] + r * hh[:, 2 * H :])
    return gi, n + u * (h - n)


def _native_step(dec: object, d64: ref.Decoder64, cache: F32, h: F32, N: int) -> F32:
    R = len(h)
    x = np.broadcast_to(d64.w["feat.mean"].astype(np.float32), (R // N, d64.n_features))
    out = {
        "rotations": np.zeros((R, 108), np.float32),
        "contacts": np.zeros((R, 2), np.float32),
        "h_out": np.zeros((R, d64.hidden), np.float32),
    }
    if d64.n_root:
        out["root"] = np.zeros((R, d64.n_root), np.float32)
    dec.step(np.ascontiguousarray(x), N, cache, h, out)  # type: ignore[attr-defined]
    return out["h_out"]


def _inputs(d64: ref.Decoder64, R: int, seed: int) -> tuple[F32, F32]:
    rng = np.random.default_rng(seed)
    cache = (rng.standard_normal((R, d64.hidden)) * 0.7).astype(np.float32)
    h = np.tanh(rng.standard_normal((R, d64.hidden))).astype(np.float32)
    return cache, h


def test_the_rounding_is_to_nearest_even_with_denormals_to_zero() -> None:
    one = 1.0
    ulp = 2.0**-7  # bf16 keeps 7 fraction bits
    x = np.array([one + ulp / 2, one + 1.5 * ulp, one + ulp / 2 + 2**-20, -3e-39, 1e-30])
    got = bf16(x.astype(np.float32))
    assert got[0] == one  # a tie goes to the even neighbour (1.0)
    assert got[1] == one + 2 * ulp  # ... and up from an odd one
    assert got[2] == one + ulp  # past the tie: up
    assert got[3] == 0.0 and np.signbit(got[3])  # a denormal: a zero of its sign
    assert got[4] != 0.0  # a small normal number stays


@pytest.mark.parametrize("name", ["cvae_decoder", "cvae_decoder_hmd3"])
def test_every_level_does_the_bf16_arithmetic_of_the_numpy_reference(
    name: str, precision: None
) -> None:
    dec, _ = native.load_native(Models(name, "anomaly", None, 2, 10, 0.2))
    d64 = ref.Decoder64.load(name)
    G, N = 3, 37  # rows that fill neither a tile nor a register block
    cache, h = _inputs(d64, G * N, 3)
    gi, want = step_bf16(d64, cache, h)
    worst = {}
    for level in LEVELS:
        native.set_native_isa(level)
        native.set_native_precision("bf16")
        worst[level] = float(np.abs(_native_step(dec, d64, cache, h, N) - want).max())
    native.set_native_precision("fp32")
    fp32 = float(np.abs(_native_step(dec, d64, cache, h, N) - want).max())
    # float32 rounding of the activations and the polynomial exp: a few 1e-7
    assert max(worst.values()) < 1e-6, worst
    # fp32 gates are off the bf16 reference by far more: the bound tells them apart
    assert fp32 > 100 * max(worst.values()), (fp32, worst)
    assert np.abs(gi).max() > 1.0  # the gates were not all near zero


@pytest.mark.parametrize("name", ["cvae_decoder", "cvae_decoder_hmd3"])
def test_bf16_holds_the_60_step_bounds_on_every_level(name: str, precision: None) -> None:
    # issue 18's bounds for bf16 against the float64 decoder: 5 mm p99 in joint
    # positions and at most 0.1 % contact flips after 60 recurrent steps
    from tests.online.inference.test_native import load_decoders, run_decoders

    for level in LEVELS:
        native.set_native_isa(level)
        native.set_native_precision("bf16")
        dec, d64 = load_decoders(name)
        w = run_decoders(dec, d64, 60, np.random.default_rng(1))
        assert w["pos_p99_last"] < 5e-3, (level, w)
        assert w["flips_last"] <= 1e-3, (level, w)
        assert w["h_last"] > 1e-4, (level, w)  # bf16, not fp32, ran


@NEEDS_BF16
@pytest.mark.parametrize("name", ["cvae_decoder", "cvae_decoder_hmd3"])
def test_the_bf16_instructions_match_the_emulation(name: str, precision: None) -> None:
    dec, _ = native.load_native(Models(name, "anomaly", None, 2, 10, 0.2))
    d64 = ref.Decoder64.load(name)
    cache, h = _inputs(d64, 5 * 40, 4)
    native.set_native_precision("bf16")
    native.set_native_isa("avx512bf16")
    assert native.native_precision() == "bf16"
    hw = _native_step(dec, d64, cache, h, 40)
    native.set_native_isa("avx512f")
    assert native.native_precision() == "bf16-emulated"
    emu = _native_step(dec, d64, cache, h, 40)
    # the same products in the same order; a CPU that rounds once per pair rather
    # than once per product moves the sums by an ulp or two
    assert float(np.abs(hw - emu).max()) < 1e-5


def _in_subprocess(**env: str) -> subprocess.CompletedProcess[str]:
    clean = {
        k: v
        for k, v in os.environ.items()
        if k not in ("POSECAST_NATIVE_ISA", "POSECAST_NATIVE_PRECISION")
    }
    code = "from posecast import _native; print(_native.isa(), _native.precision())"
    return subprocess.run(
        [sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True
    )


def test_bf16_is_the_default_only_where_the_instructions_are() -> None:
    r = _in_subprocess()
    level, prec = r.stdout.split()
    assert level == LEVELS[0]
    assert prec == ("bf16" if level == "avx512bf16" else "fp32")
    for lv in LEVELS:
        r = _in_subprocess(POSECAST_NATIVE_ISA=lv)
        assert r.stdout.split() == [lv, "bf16" if lv == "avx512bf16" else "fp32"], r.stderr


def test_posecast_native_precision_overrides_the_default() -> None:
    for p in ("fp32", "bf16"):
        r = _in_subprocess(POSECAST_NATIVE_PRECISION=p)
        assert r.returncode == 0 and r.stdout.split() == [LEVELS[0], p], r.stderr
    r = _in_subprocess(POSECAST_NATIVE_PRECISION="fp16")
    assert r.returncode != 0 and "POSECAST_NATIVE_PRECISION=fp16" in r.stderr


def test_set_precision_takes_only_the_two_names(precision: None) -> None:
    with pytest.raises(ValueError, match="unknown precision"):
        native.set_native_precision("int8")
    native.set_native_precision("bf16")
    native.set_native_isa("generic")
    assert native.native_precision() == "bf16-emulated"
