"""The client processes of ``posecast bench latency --sdk typescript``: Node processes
running the TypeScript SDK (``client_sdk/typescript/bench/latency-worker.ts``), each
doing what one Python client process does (:mod:`.players`), read back into the same
:class:`~.players.WorkerResult`.

Python prepares what the Node side needs and reads what it measured:

- **the worker**, bundled once per run with the package's esbuild
  (``scripts/build-bench.mjs``) into a temporary folder (:func:`build_worker`);
- **the walks**: each player's frames from the Python SDK's
  :class:`posecast_client.WalkSource` (the same seed, offset and length as the Python
  players stream), float64 in a file per process, so both SDK modes stream one motion
  (:func:`write_walks`);
- **the plan** (JSON): the server's URL, each player's token (minted here), room,
  role, and first frame time (the run's start plus the phase a Python player draws
  from its seed); the measured window.

Every time on both sides is the host's ``CLOCK_MONOTONIC``: ``time.monotonic()`` here,
``process.hrtime.bigint()`` there (libuv's ``uv_hrtime``). Each Node process reports
its clock at start-up, and :func:`node_workers` checks it against ``time.monotonic()``
read just before the spawn: a worker on another clock is an error, never a figure.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import random
import shutil
import subprocess
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import posecast_client as pc

from posecast.errors import WorkerError
from posecast.offline.evaluation.latency.players import TAIL_S, PlayerPlan, WorkerPlan, WorkerResult

TS_SDK = Path(__file__).resolve().parents[5] / "client_sdk" / "typescript"
NPM_HINT = "cd client_sdk/typescript && npm ci"
_CLOCK_SLACK_S = 30.0  # a worker's clock at start-up lies within this of its spawn


def node_missing(ts_dir: Path | None = None) -> str | None:
    """Why the TypeScript players cannot run here (``None``: they can): no ``node`` on
    the PATH, no checkout of the SDK (``ts_dir``, default :data:`TS_SDK`), or its
    ``node_modules`` not installed."""
    ts_dir = TS_SDK if ts_dir is None else ts_dir
    if shutil.which("node") is None:
        return "no `node` on the PATH (Node 20 or newer runs the TypeScript SDK)"
    if not (ts_dir / "bench" / "latency-worker.ts").is_file():
        return f"no TypeScript SDK checkout at {ts_dir} (run from a clone of the repository)"
    for package in ("esbuild", "ws"):
        if not (ts_dir / "node_modules" / package).is_dir():
            return (
                f"no {package!r} in {ts_dir / 'node_modules'}: the SDK's packages are not installed"
            )
    return None


def build_worker(out_dir: Path, ts_dir: Path | None = None) -> Path:
    """Bundle the worker into ``out_dir``; the path of the bundle."""
    ts_dir = TS_SDK if ts_dir is None else ts_dir
    script = ts_dir / "scripts" / "build-bench.mjs"
    done = subprocess.run(
        ["node", str(script), "--out", str(out_dir)],
        cwd=ts_dir, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    bundle = out_dir / "latency-worker.cjs"
    if done.returncode != 0 or not bundle.is_file():
        raise WorkerError(
            f"building the TypeScript latency worker failed: {done.stderr.strip()[-2000:]}",
            worker=-1, status=done.returncode,
        )  # fmt: skip
    return bundle


def walk_seconds(warmup_s: float, seconds: float) -> float:
    """The walk's length: what :mod:`.players` gives its ``WalkSource`` (long enough
    not to loop within the run; a loop would jump each walker back to its start)."""
    return max(10.0, warmup_s + seconds + 2.0)


Walks = tuple[Path, dict[str, tuple[int, int]]]  # a walks file, each player's frames in it


def write_walks(
    players: Sequence[PlayerPlan], path: Path, *, seconds: float, frame_hz: float = 60.0
) -> Walks:
    """Each player's walk, as a Python player streams it (``WalkSource`` with its seed
    and its ``slot``'s offset), into ``path``: float64 little-endian, 29 numbers a
    frame (4 x 3 positions, 4 x 4 xyzw orientations, the valid mask). Returns each
    player's first frame and frame count in the file."""
    rows, at = [], {}
    first = 0
    for p in players:
        offset = ((p.slot % 4) * 1.2, 0.0, (p.slot // 4) * 1.2)  # side by side, as players.py
        source = pc.WalkSource(seconds=seconds, seed=p.seed, loop=True, offset_m=offset,
                               rate_hz=frame_hz)  # fmt: skip
        n = source.n_frames
        valid = [s.valid for s in itertools.islice(source.samples(), n)]
        rows.append(np.concatenate([source.positions.reshape(n, 12),
                                    source.orientations.reshape(n, 16),
                                    np.asarray(valid, np.float64)[:, None]], axis=1))  # fmt: skip
        at[p.player] = (first, n)
        first += n
    np.concatenate(rows).astype("<f8").tofile(path)
    return path, at


def node_plan(plan: WorkerPlan, walks: Path, frames: dict[str, tuple[int, int]]) -> dict[str, Any]:
    """The Node worker's plan (JSON) for ``plan``: players.py's roles, phases and
    tokens, decided here."""
    players, drawn = [], set()
    for p in plan.players:
        draws = plan.draw_all or p.room not in drawn  # the first of its room here
        drawn.add(p.room)
        phase = random.Random(p.seed).random() / plan.frame_hz  # as players.py draws it
        first, n = frames[p.player]
        players.append({
            "player": p.player, "room": p.room, "draws": draws,
            "token": pc.mint_token(plan.secret, room=p.room, player=p.player),
            "start_at": plan.start_at + phase, "first": first, "frames": n,
        })  # fmt: skip
    return {
        "url": plan.url, "protocol": plan.protocol, "walks": str(walks), "players": players,
        "measure_from": plan.measure_from, "stop_at": plan.stop_at, "tail_s": TAIL_S,
        "display_hz": plan.display_hz, "frame_hz": plan.frame_hz,
    }  # fmt: skip


def result_of(data: dict[str, Any]) -> WorkerResult:
    """A Node worker's RESULT.json as the :class:`WorkerResult` a Python worker returns."""
    return WorkerResult(
        captures={p: {int(s): float(t) for s, t in rows} for p, rows in data["captures"].items()},
        displayed=[(str(s), int(q), float(t), float(r), float(w))
                   for s, q, t, r, w in data["displayed"]],
        drawn=int(data["drawn"]),
        waiting=[(str(s), int(q), float(t), float(r)) for s, q, t, r in data["waiting"]],
        jumps_m=[float(j) for j in data["jumps_m"]],
        members=dict(data["members"]),
        welcome=dict(data["welcome"]),
        errors=Counter({str(k): int(v) for k, v in data["errors"].items()}),
        failures=[str(f) for f in data["failures"]],
        display_frames=int(data["display_frames"]),
        display_frames_late=int(data["display_frames_late"]),
        cpu_s=float(data["cpu_s"]),
        wall_s=float(data["wall_s"]),
    )  # fmt: skip


@contextlib.contextmanager
def node_workers(
    bundle: Path, plans: Sequence[WorkerPlan], walks: Sequence[Walks], work_dir: Path
) -> Iterator[Callable[[float], list[WorkerResult]]]:
    """Start one Node worker per plan (``walks[k]``: its walks, from
    :func:`write_walks`); yields ``results(timeout_s)``, which waits for them all.
    Workers still running on the way out are killed."""
    procs: list[tuple[subprocess.Popen[bytes], Path, float]] = []
    try:
        for k, (plan, (walk, frames)) in enumerate(zip(plans, walks, strict=True)):
            plan_path = work_dir / f"plan{k}.json"
            plan_path.write_text(json.dumps(node_plan(plan, walk, frames)))
            out = work_dir / f"result{k}.json"
            out.unlink(missing_ok=True)
            spawned = time.monotonic()
            proc = subprocess.Popen(
                ["node", str(bundle), str(plan_path), str(out)],
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            )  # fmt: skip
            procs.append((proc, out, spawned))

        def results(timeout_s: float) -> list[WorkerResult]:
            deadline = time.monotonic() + timeout_s
            got = []
            for k, (proc, out, spawned) in enumerate(procs):
                try:
                    _, err = proc.communicate(timeout=max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    raise WorkerError(f"latency worker {k} (node) ran past {timeout_s:.0f} s",
                                      worker=k, status=None) from None  # fmt: skip
                if proc.returncode != 0 or not out.is_file():
                    raise WorkerError(
                        f"latency worker {k} (node) exited {proc.returncode}: "
                        f"{err.decode(errors='replace').strip()[-2000:]}",
                        worker=k, status=proc.returncode,
                    )  # fmt: skip
                data = json.loads(out.read_text())
                check_clock(float(data["started_at"]), spawned, k)
                got.append(result_of(data))
            return got

        yield results
    finally:
        for proc, _, _ in procs:
            if proc.poll() is None:
                proc.kill()
            with contextlib.suppress(Exception):
                proc.communicate(timeout=10)


def check_clock(started_at: float, spawned: float, worker: int) -> None:
    """A worker's clock at start-up (``started_at``) must follow ``time.monotonic()``
    read just before its spawn (``spawned``) by under :data:`_CLOCK_SLACK_S`: the two
    are one clock, or every figure would be off by their offset."""
    if not spawned <= started_at < spawned + _CLOCK_SLACK_S:
        raise WorkerError(
            f"latency worker {worker} (node) is not on this host's CLOCK_MONOTONIC: it "
            f"started at {started_at:.6f} s, spawned at {spawned:.6f} s",
            worker=worker, status=None,
        )  # fmt: skip
