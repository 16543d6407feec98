"""``posecast bench engine``: the whole per-tick work of the SSI engine on this machine.

Each measured tick is everything the server's tick loop does for the engine: input
features, the batched decoder call, FK, contact IK and anomaly scoring of every
sample, selection, and emission with look-ahead (including interpolation re-decodes
when transitions run). Players replay a generated walk, each from its own phase.

With ``hmd3_share`` above 0 both shipped models are loaded (a :class:`MultiEngine`,
as ``posecast serve`` runs them) and that share of the players is headset-only: each
model steps its own players in one batch, so a tick costs two decoder calls.

With ``sets`` every player is on the one model of every tracker set (``sites``), the
players taking the six sets of the evaluation table in turn (3, 4, 6, 8 positional
points, 3 + 2 and 3 + 4 inertial): mixed sets in one batch, one decoder call a tick,
measured beside the single-layout figure (``hmd3+waist``) count by count.

Every figure is for one backend (``native``, ``onnx`` or ``torch``); the report names
the one that ran, which is ``onnx`` where ``native`` was asked for and could not load.
"""

from __future__ import annotations

import os
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.offline.train.masks import TABLE_SETS
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine, load_multi_engine
from posecast.tracking.layouts import Layout
from posecast.tracking.sites import Kind, TrackerSet, site_tracks

FRAME_BUDGET_MS = 1000.0 / 60.0
# Multiply-accumulates per sample per frame (decoder FC + GRU + heads, anomaly AE),
# from the layer sizes; FK and IK add a few hundred more and are not counted.
MAC_PER_SAMPLE = (
    (24 + 30) * 128
    + 2 * 128 * 384
    + 128 * 110
    + (57 * 28 + 28 * 14 + 14 * 7 + 7 * 7 + 7 * 14 + 14 * 28 + 28 * 108)
)


@dataclass(frozen=True)
class BenchResult:
    players: int
    samples: int
    hmd3_players: int
    backend: str  # the backend that ran
    tick_p50_ms: float
    tick_p99_ms: float
    gflops: float
    rss_mb: float

    def realtime(self) -> bool:
        return fits_frame(self.tick_p99_ms)


def fits_frame(p99_ms: float, budget_ms: float = FRAME_BUDGET_MS) -> bool:
    """The one rule for a count of players holding 60 Hz: its p99 tick fits the frame
    (under ``budget_ms``). :meth:`BenchResult.realtime`, :func:`max_realtime_players`
    and :func:`realtime_summary` all judge by it."""
    return p99_ms < budget_ms


def max_realtime_players(
    players: list[int], p99_ms: list[float], budget_ms: float = FRAME_BUDGET_MS
) -> int:
    """The report's ``max_realtime_players``: the largest tested count that fits the
    frame (:func:`fits_frame`), 0 when none did."""
    return max(
        (p for p, t in zip(players, p99_ms, strict=True) if fits_frame(t, budget_ms)), default=0
    )


def realtime_summary(
    players: list[int], p99_ms: list[float], budget_ms: float = FRAME_BUDGET_MS
) -> str:
    """How many players hold 60 Hz, as far as the tested counts tell: the largest count
    that fits (:func:`max_realtime_players`) and the next tested count, which did not
    (``"25 (30 did not fit)"``); ``">= 4 (every tested count fit)"`` when the largest
    fit, so the real limit is higher; ``"none of the tested counts fit (the smallest,
    1, took p99 20.3 ms)"``. A count below the largest that fits which did not fit is
    named too (a noisy run). ASCII only: it is printed, and stdout may not be UTF-8."""
    best = max_realtime_players(players, p99_ms, budget_ms)
    runs = sorted(zip(players, p99_ms, strict=True))
    if not any(fits_frame(t, budget_ms) for t in p99_ms):
        smallest, took = runs[0]
        return f"none of the tested counts fit (the smallest, {smallest}, took p99 {took:.1f} ms)"
    failed = sorted({p for p, t in runs if not fits_frame(t, budget_ms)})
    above = [p for p in failed if p > best]
    below = [p for p in failed if p < best]
    text = f"{best} ({above[0]} did not fit)" if above else f">= {best} (every tested count fit)"
    if below:
        text += f"; {', '.join(map(str, below))} did not fit either, a noisy run"
    return text


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:  # pragma: no cover - non-Linux
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def bench_frames(seconds: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """The benchmarks' trackers: a generated walk's positions ``(T, 4, 3)`` and
    orientations ``(T, 4, 4)``, float64 (also ``benchmarks/shown_pose.py`` and
    ``decoders.py``)."""
    fr = derive_frames(walk_clip(seconds, 60.0, seed=3))
    return fr["tracker_pos"].astype(np.float64), fr["tracker_quat"].astype(np.float64)


def bench(
    players: int,
    samples: int = 100,
    ticks: int = 120,
    warmup: int = 20,
    threads: int = 2,
    lookahead: int | None = None,
    hmd3_share: float = 0.0,
    backend: str = "native",
    sets: bool = False,
) -> BenchResult:
    # The served look-ahead unless told (``lookahead``: the paper's delayed emission).
    cfg = (
        EngineConfig(samples=samples)
        if lookahead is None
        else EngineConfig(samples=samples, lookahead=lookahead, delayed_emission=True)
    )
    n3 = round(hmd3_share * players)
    engine: Engine | MultiEngine
    if sets:
        return _bench_sets(players, samples, ticks, warmup, threads, cfg, backend)
    if hmd3_share > 0:
        engine = load_multi_engine(cfg, (Layout.HMD3_WAIST, Layout.HMD3), None, threads, backend)
        used = "+".join(sorted(set(engine.backends.values())))
    else:
        engine = load_engine(cfg, None, threads, Layout.HMD3_WAIST, backend, capacity=players)
        used = engine.backend_name
    rss0 = _rss_mb()
    for p in range(players):
        if isinstance(engine, MultiEngine):
            engine.add_player(f"p{p}", p, Layout.HMD3 if p < n3 else Layout.HMD3_WAIST)
        else:
            engine.add_player(f"p{p}", seed=p)
    pos, quat = bench_frames()
    ms = _timed_ticks(
        engine,
        players,
        warmup,
        ticks,
        lambda t, p, k: TrackerFrame(t, pos[k], quat[k]),
        len(pos),
    )
    flop = 2.0 * MAC_PER_SAMPLE * players * samples
    return _result(players, samples, n3, used, ms, flop, rss0)


def _timed_ticks(
    engine: Engine | MultiEngine,
    players: int,
    warmup: int,
    ticks: int,
    frame: Callable[[int, int, int], TrackerFrame],
    frames: int,
) -> np.ndarray:
    """Milliseconds of each measured tick: every tick, player ``p`` pushes
    ``frame(t, p, k)`` (``k`` its own phase of the ``frames``-long clip), then the
    engine ticks; the first ``warmup`` ticks are not kept."""
    times = []
    for t in range(warmup + ticks):
        for p in range(players):
            engine.push(f"p{p}", frame(t, p, (t + 37 * p) % frames))
        t0 = time.perf_counter()
        engine.tick()
        if t >= warmup:
            times.append(time.perf_counter() - t0)
    return np.array(times) * 1000.0


def _result(
    players: int,
    samples: int,
    hmd3_players: int,
    backend: str,
    ms: np.ndarray,
    flop: float | None,
    rss0: float,
) -> BenchResult:
    """The figures of one run from its tick times (``flop`` per tick, ``None``: not
    counted, GFLOP/s 0)."""
    p50 = float(np.percentile(ms, 50))
    return BenchResult(
        players=players,
        samples=samples,
        hmd3_players=hmd3_players,
        backend=backend,
        tick_p50_ms=round(p50, 3),
        tick_p99_ms=round(float(np.percentile(ms, 99)), 3),
        gflops=0.0 if flop is None else round(flop / (p50 / 1000.0) / 1e9, 2),
        rss_mb=round((_rss_mb() - rss0) / max(1, players), 3),
    )


def _site_frames(seconds: float = 8.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The walk's synthetic trackers on every site: positions, orientations and
    accelerations, ``(F, 10, ...)``."""
    clip = walk_clip(seconds, 60.0, seed=3)
    return site_tracks(*clip.fk(), 60.0)


def _bench_sets(
    players: int,
    samples: int,
    ticks: int,
    warmup: int,
    threads: int,
    cfg: EngineConfig,
    backend: str,
) -> BenchResult:
    """:func:`bench` with every player on the ``sites`` model, the table's sets in turn."""
    engine = load_engine(cfg, None, threads, Layout.SITES, backend, capacity=players)
    sets = [TrackerSet.parse(s) for s in TABLE_SETS.values()]
    rss0 = _rss_mb()
    for p in range(players):
        engine.add_player(f"p{p}", seed=p, tracker_set=sets[p % len(sets)])
    pos, quat, acc = _site_frames()
    inertial = [(ts.kinds() == Kind.INERTIAL)[:, None] for ts in sets]
    values = [np.where(i, acc, pos) for i in inertial]  # (F, 10, 3) per set
    ms = _timed_ticks(
        engine,
        players,
        warmup,
        ticks,
        lambda t, p, k: TrackerFrame(t, values[p % len(sets)][k], quat[k]),
        len(pos),
    )
    # GFLOP/s not counted: the sites decoder's input layer is wider than MAC_PER_SAMPLE's.
    return _result(players, samples, 0, engine.backend_name, ms, None, rss0)


def naive_loop(
    players: int, samples: int = 100, ticks: int = 60, threads: int = 2, backend: str = "native"
) -> float:
    """p50 tick (ms) when each player has its own engine, stepped one after another."""
    cfg = EngineConfig(samples=samples)
    one = load_engine(cfg, None, threads, Layout.HMD3_WAIST, backend, capacity=1)
    engines = []
    for p in range(players):  # every engine on the one backend's decoder and pool
        e = Engine(one.decoder, one.pool, cfg, 1, backend_name=one.backend_name)
        e.add_player("p", seed=p)
        engines.append(e)
    pos, quat = bench_frames()
    times = []
    for t in range(10 + ticks):
        t0 = time.perf_counter()
        for p, e in enumerate(engines):
            k = (t + 37 * p) % len(pos)
            e.push("p", TrackerFrame(t, pos[k], quat[k]))
            e.tick()
        if t >= 10:
            times.append(time.perf_counter() - t0)
    return round(float(np.percentile(np.array(times) * 1000.0, 50)), 3)


def run_side_by_side(
    backends: list[str],
    player_counts: list[int],
    samples: int,
    threads: int,
    ticks: int,
    naive_players: int,
    hmd3_share: float = 0.0,
    sets: bool = False,
) -> list[dict[str, Any]]:
    """One report per backend, measured side by side: every player count runs on each
    backend in turn before the next count, so a change in the machine's load between
    counts moves all backends alike and their ratio stays meaningful."""
    firsts = [
        bench(player_counts[0], samples, ticks=ticks, threads=threads, backend=b) for b in backends
    ]
    used = [f.backend for f in firsts]  # a fallback is taken (and logged) once
    results = [[f] for f in firsts]
    for p in player_counts[1:]:
        for i, b in enumerate(used):
            results[i].append(bench(p, samples, ticks=ticks, threads=threads, backend=b))
    both: list[list[BenchResult]] = [[] for _ in backends]
    if hmd3_share > 0:
        for p in player_counts:
            for i, b in enumerate(used):
                both[i].append(
                    bench(
                        p, samples, ticks=ticks, threads=threads, hmd3_share=hmd3_share, backend=b
                    )
                )
    mixed_sets: list[list[BenchResult]] = [[] for _ in backends]
    if sets:  # beside the single-layout figure: each count right after it, per backend
        for j, p in enumerate(player_counts):
            for i, b in enumerate(used):
                mixed_sets[i].append(
                    bench(p, samples, ticks=ticks, threads=threads, backend=b, sets=True)
                )
                results[i][j] = bench(p, samples, ticks=ticks, threads=threads, backend=b)
    naive = [
        {
            "players": naive_players,
            "tick_p50_ms": naive_loop(naive_players, samples, threads=threads, backend=b),
            "batched_tick_p50_ms": bench(
                naive_players, samples, ticks=60, threads=threads, backend=b
            ).tick_p50_ms,
        }
        for b in used
    ]
    return [
        report(asked, b, results[i], both[i], naive[i], samples, threads, hmd3_share)
        | (_sets_report(mixed_sets[i], results[i]) if sets else {})
        for i, (asked, b) in enumerate(zip(backends, used, strict=True))
    ]


def _sets_report(mixed: list[BenchResult], single: list[BenchResult]) -> dict[str, Any]:
    return {
        "mixed_sets": {
            "backend": mixed[0].backend,
            "sets": list(TABLE_SETS),
            "tick_p50_ms": [r.tick_p50_ms for r in mixed],
            "tick_p99_ms": [r.tick_p99_ms for r in mixed],
            # p50 of the mixed sets over the 4-point model's, measured right after it
            "p50_ratio": [
                round(m.tick_p50_ms / max(s.tick_p50_ms, 1e-9), 3)
                for m, s in zip(mixed, single, strict=True)
            ],
            "max_realtime_players": _max_realtime(mixed),
            "rss_mb_per_player": [r.rss_mb for r in mixed],
        }
    }


def _max_realtime(results: list[BenchResult]) -> int:
    return max_realtime_players([r.players for r in results], [r.tick_p99_ms for r in results])


def _isa(backend: str) -> str | None:
    """The native kernels' instruction-set level, for a native report."""
    if "native" not in backend:
        return None
    from posecast.online.inference.native import native_isa

    return native_isa()


def _precision(backend: str) -> str:
    """The GRU gates' arithmetic: the native kernels' (``fp32``, ``bf16``,
    ``bf16-emulated``), fp32 on the other backends."""
    if "native" not in backend:
        return "fp32"
    from posecast.online.inference.native import native_precision

    return native_precision()


def report(
    asked: str,
    backend: str,
    results: list[BenchResult],
    both: list[BenchResult],
    naive: dict[str, Any],
    samples: int,
    threads: int,
    hmd3_share: float,
) -> dict[str, Any]:
    mixed: dict[str, Any] = {}
    if both:
        mixed = {
            "backend": both[0].backend,
            "hmd3_share": hmd3_share,
            "hmd3_players": [r.hmd3_players for r in both],
            "tick_p50_ms": [r.tick_p50_ms for r in both],
            "tick_p99_ms": [r.tick_p99_ms for r in both],
            "max_realtime_players": _max_realtime(both),
            "rss_mb_per_player": [r.rss_mb for r in both],
        }
    return {
        "backend": backend,
        "backend_asked": asked,
        "native_isa": _isa(backend),
        "precision": _precision(backend),
        "players": [r.players for r in results],
        "samples": samples,
        "tick_p50_ms": [r.tick_p50_ms for r in results],
        "tick_p99_ms": [r.tick_p99_ms for r in results],
        "max_realtime_players": _max_realtime(results),
        "gflops": [r.gflops for r in results],
        "rss_mb_per_player": [r.rss_mb for r in results],
        "naive_loop": naive,
        "threads": threads,
        "frame_budget_ms": round(FRAME_BUDGET_MS, 3),
    } | ({"both_models": mixed} if mixed else {})
