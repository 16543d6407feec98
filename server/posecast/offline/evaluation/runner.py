"""Run the evaluation variants over a list of clips and aggregate their metrics."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from posecast.body.forecast import SPAN, forecast
from posecast.body.passes import Passes
from posecast.body.pelvis import pelvis_poses
from posecast.body.pipeline import Decoded, ShownState, show
from posecast.geometry.rotations import mat2quat, quat2mat
from posecast.offline.dataset.frames import Frames
from posecast.offline.evaluation import metrics as m
from posecast.offline.evaluation import plausibility as pl
from posecast.offline.evaluation.reconstruct import (
    clip_truth,
    decode_ae,
    decode_cvae,
    pose_from_rotations,
)
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.anomaly import AnomalyScorer
from posecast.online.inference.artifact import Artifact, load_artifact
from posecast.online.inference.auto import Backend, load_backend
from posecast.online.inference.loader import kernels
from posecast.skeleton import LOWER_BODY, NUM_ROTATIONS
from posecast.tracking.features import TrackerSlot
from posecast.tracking.layouts import Layout, PlayerLayout, model_layout, pelvis_from_head, spec
from posecast.tracking.sites import (
    IMU_ACC_BIAS,
    IMU_ACC_NOISE,
    Kind,
    TrackerSet,
    clip_site_features,
    imu_noise,
    site_tracks,
)

# The pose a server emits at tick n against the truth at frame n (what a room-mate
# sees now): a variant emitting frame n - d at tick n is compared over n >= d.
PRESENT_KEYS = (
    "present_mpjpe_cm",
    "present_lower_mpjpe_cm",
    "present_head_pe_cm",
    "present_hand_pe_cm",
    "present_root_pe_cm",
)
# A variant's stream forecast h frames ahead (body.forecast) against holding its last
# pose, both against the truth h frames after the tick (33, 67, 100 ms at 60 fps), and
# the bound of any forecast of that stream: its own pose at n + h (a perfect forecast).
FORECAST_FRAMES = (2, 4, 6)
FORECAST_KEYS = tuple(
    f"{kind}_{round(h * 1000 / 60)}ms_mpjpe_cm"
    for h in FORECAST_FRAMES
    for kind in ("hold", "forecast", "bound")
)
VARIANTS = ("cvae_1sample", "cvae_ik", "cvae_ik_ssi", "ae_ik", "baseline_mean_lower_body")
FLAG_KEYS = ("flagged_rate", *(f"flagged_{c}_rate" for c in pl.CATEGORIES))
METRIC_KEYS = (
    "mpjpe_cm",
    "lower_mpjpe_cm",
    "head_pe_cm",
    "hand_pe_cm",
    "hand_rot_err_deg",
    "mpjre_deg",
    "jitter",
    "root_pe_cm",
    *FLAG_KEYS,
    "transitions_per_min",
    *PRESENT_KEYS,
    *FORECAST_KEYS,
    "mpjve_cm_s",
    "mpjae_cm_s2",
    "foot_skate_cm_s",
    "ground_penetration_cm",
    "implausible_rate",
)


def _mean_leg_pose(meta: dict[str, Any]) -> np.ndarray | None:
    mean = meta.get("mean_pose_rot6d")
    return None if mean is None else np.asarray(mean, dtype=np.float64).reshape(NUM_ROTATIONS, 6)


@dataclass(frozen=True)
class Tracks:
    """What a clip's player sends, frame by frame, in the engine's rows (4 tracker
    slots, or the ten sites of a tracker set): ``values`` ``(T, rows, 3)`` positions
    (an inertial site's acceleration), ``quat`` ``(T, rows, 4)``; and the network's
    input ``features`` ``(T, F)``. Rows 0-3 are head, hands and waist either way."""

    values: np.ndarray
    quat: np.ndarray
    features: np.ndarray


def clip_tracks(
    fr: Frames,
    fps: float,
    layout: PlayerLayout,
    seed: int = 0,
    acc_noise: float = IMU_ACC_NOISE,
    acc_bias: float = IMU_ACC_BIAS,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
) -> Tracks:
    """The trackers of ``layout`` on a clip. A tracker set's sites sit on their joints of
    the true pose (:func:`~posecast.tracking.sites.site_tracks`; ``truth``: the clip's
    world rotations and positions when the caller has them already); its inertial
    sites' accelerations get the training's sensor noise (``acc_noise`` white,
    ``acc_bias`` held over the clip, m/s^2), drawn from ``seed``."""
    if not isinstance(layout, TrackerSet):
        ls = spec(layout)
        features = (
            fr["features"]
            if ls.layout is Layout.HMD3_WAIST
            else ls.clip_features(fr["tracker_pos"], fr["tracker_quat"], fps)
        )
        return Tracks(
            fr["tracker_pos"].astype(np.float64),
            fr["tracker_quat"].astype(np.float64),
            np.asarray(features, np.float32),
        )
    kinds = layout.kinds()
    true_mat, true_pos = truth or clip_truth(fr)
    pos, quat, acc = site_tracks(true_mat, true_pos, fps)
    acc = acc + imu_noise(np.random.default_rng(seed), len(acc), acc_noise, acc_bias)
    values = np.where((kinds == Kind.INERTIAL)[:, None], acc, pos)
    features = clip_site_features(pos, quat, acc, kinds, fps).astype(np.float32)
    return Tracks(values, quat, features)


def evaluate(
    clips: Sequence[Frames],
    fps: float,
    variants: Sequence[str] = VARIANTS,
    models_dir: str | Path | None = None,
    log: Callable[[str], None] | None = None,
    engine_cfg: EngineConfig | None = None,
    layout: PlayerLayout | str = Layout.HMD3_WAIST,
    backend: str = "native",
) -> dict[str, Any]:
    """Metrics per variant over ``clips`` (each a :data:`Frames` dict with ground truth),
    for the model of tracker ``layout`` (a named layout, or a
    :class:`~posecast.tracking.sites.TrackerSet` for the one model of every set). The
    full method (``cvae_ik_ssi``) runs the SSI engine on ``backend`` (the report's
    ``backend`` names the one that ran), and the ``_ik`` variants that backend's shown
    pose passes; the networks of the other variants and the scores behind
    ``implausible_rate`` run on ONNX Runtime.

    ``baseline_mean_lower_body`` takes the true upper body and pelvis whatever the
    layout, so only its lower-body numbers are a floor to beat.

    ``cvae_ik`` and ``ae_ik`` are what the server would stream without SSI: the
    network's one sample (the prior's mean; the AE's pose) through the engine's own
    shown-pose passes, :func:`posecast.body.pipeline.show` with ``engine_cfg``'s
    switches, frame by frame (:func:`run_shown`), so that ``cvae_ik_ssi`` against
    ``cvae_ik`` measures SSI alone.
    ``cvae_1sample`` is the network's raw pose.
    """
    player_layout = layout if isinstance(layout, TrackerSet) else Layout(layout)
    ls = spec(model_layout(player_layout))
    tracker_set = player_layout if isinstance(player_layout, TrackerSet) else None
    dec = load_artifact(ls.decoder, models_dir)
    scorer = AnomalyScorer(load_artifact(ls.anomaly, models_dir))
    if "ae_ik" in variants and ls.layout is not Layout.HMD3_WAIST:
        raise ValueError("the AE ablation (ae_ik) exists for the 4-point layout only")
    ae = load_artifact("ae_step", models_dir) if "ae_ik" in variants else None
    latent = int(dec.meta["model_config"]["latent"])
    base = dec if ls.layout is Layout.HMD3_WAIST else load_artifact("cvae_decoder", models_dir)
    mean_pose = _mean_leg_pose(base.meta)
    leg_rot = [int(j) - 1 for j in LOWER_BODY]  # rotation rows of the leg joints
    results: dict[str, Any] = {}
    truth = [clip_truth(fr) for fr in clips]
    tracks = [
        clip_tracks(fr, fps, player_layout, seed=i, truth=truth[i]) for i, fr in enumerate(clips)
    ]
    # The pelvis of a single-sample variant: the waist tracker's, or the decoder's own.
    root_from_waist = tracker_set.tracks_waist if tracker_set is not None else not ls.predicts_root
    engine_cfg = engine_cfg or EngineConfig()
    delay = engine_cfg.delay  # ticks the engine's poses (and the _ik variants') lag
    kinds = tracker_set.kinds() if tracker_set is not None else None
    shown_by = (
        load_backend(backend, ls.layout, models_dir, cfg=engine_cfg)
        if any(v == "cvae_ik_ssi" or v.endswith("_ik") for v in variants)
        else None
    )
    for name in variants:
        acc, t0 = m.Accumulator(), time.perf_counter()
        poses: list[tuple[np.ndarray, np.ndarray]] = []
        transitions = 0
        if name == "cvae_ik_ssi":
            assert shown_by is not None
            ssi = run_ssi(shown_by, tracks, engine_cfg, tracker_set)
            poses = [(wm, wp) for wm, wp, _ in ssi]
            transitions = sum(n for _, _, n in ssi)
        elif name.endswith("_ik"):
            assert shown_by is not None
            one = [_decode(name, dec, ae, tr, root_from_waist, latent) for tr in tracks]
            poses = run_shown(shown_by.pool, one, tracks, engine_cfg, root_from_waist, kinds)
        elif name == "cvae_1sample":
            for fr, tr in zip(clips, tracks, strict=True):
                rot, _, root = decode_cvae(dec, tr.features, np.zeros(latent, np.float32))
                root_mat, root_pos = _true_waist(fr)
                if root is not None and not root_from_waist:
                    head_pos = tr.values[:, TrackerSlot.HEAD]
                    head_quat = tr.quat[:, TrackerSlot.HEAD]
                    root_mat, root_pos = pelvis_from_head(root, head_pos, head_quat)
                poses.append(pose_from_rotations(rot, root_mat, root_pos))
        elif name == "baseline_mean_lower_body":
            if mean_pose is None:
                raise ValueError("the decoder sidecar has no mean_pose_rot6d")
            for fr in clips:
                rot = fr["rot6d"].astype(np.float64).copy()  # upper body: ground truth
                rot[:, leg_rot] = mean_pose[leg_rot]
                poses.append(pose_from_rotations(rot, *_true_waist(fr)))
        else:
            raise ValueError(f"unknown variant {name!r}")
        # The engine's variants emit frame n - delay at tick n; the others at once.
        lag = delay if name == "cvae_ik_ssi" or name.endswith("_ik") else 0
        for ci, fr in enumerate(clips):
            wm, wp = poses[ci]
            gt_mat, gt = truth[ci]
            acc.add("mpjpe_cm", m.mpjpe(wp, gt))
            acc.add("lower_mpjpe_cm", m.lower_mpjpe(wp, gt))
            acc.add("mpjve_cm_s", m.mpjve(wp, gt, fps))
            acc.add("mpjae_cm_s2", m.mpjae(wp, gt, fps))
            acc.add("foot_skate_cm_s", m.foot_skate(wp, fr["contacts"], fps))
            acc.add("ground_penetration_cm", m.ground_penetration(wp))
            # Each pose is scored with its own pelvis (the waist tracker's for 4 points).
            scores = scorer.score_mats(wp, wp[:, 0], wm[:, 0])
            acc.add("implausible_rate", m.implausible(scores, scorer.threshold_m))
            acc.add("root_pe_cm", m.root_pe(wp, gt))
            acc.add("hand_pe_cm", m.hand_pe(wp, gt))
            acc.add("head_pe_cm", m.head_pe(wp, gt))
            acc.add("hand_rot_err_deg", m.hand_rot_err(wm, gt_mat))
            acc.add("mpjre_deg", m.mpjre(wm, gt_mat))
            acc.add("jitter", m.jitter(wp, fps))
            for key, pair in m.flag_rates(pl.flags(wm, wp, fps)).items():
                acc.add(key, pair)
            for key, pair in m.present(wp, gt, lag).items():
                acc.add(key, pair)
            for key, pair in _forecast_errors(wm, wp, gt, lag, fps).items():
                acc.add(key, pair)
        means = acc.means()
        if name == "cvae_ik_ssi":
            minutes = sum(len(fr["features"]) for fr in clips) / fps / 60.0
            means["transitions_per_min"] = transitions / minutes
        res: dict[str, Any] = {k: round(v, 4) for k, v in means.items()}
        res["seconds"] = round(time.perf_counter() - t0, 2)
        results[name] = res
        if log:
            log(f"{name}: {res['seconds']:.1f} s")
    gt_acc = m.Accumulator()
    for gt_mat, gt in truth:
        gt_acc.add("jitter", m.jitter(gt, fps))
        for key, pair in m.flag_rates(pl.flags(gt_mat, gt, fps)).items():
            gt_acc.add(key, pair)
    ground_truth = {k: round(v, 4) for k, v in gt_acc.means().items()}
    return {
        "layout": str(player_layout),
        "backend": shown_by.name if shown_by is not None else None,
        # the native kernels' level and GRU precision (fp32, bf16, bf16-emulated)
        "kernels": kernels(shown_by.name) if shown_by is not None else None,
        "variants": results,
        "clips": len(clips),
        "frames": int(sum(len(c["features"]) for c in clips)),
        "fps": fps,
        "implausible_threshold_m": scorer.threshold_m,
        "ground_truth": ground_truth,
    }


def _forecast_errors(
    wm: np.ndarray, wp: np.ndarray, gt: np.ndarray, lag: int, fps: float
) -> dict[str, m.Acc]:
    """The stream emitted at tick ``n`` (frame ``n - lag`` of ``wm (T, 19, 3, 3)``,
    ``wp (T, 19, 3)``), forecast ``h`` frames ahead from its last poses
    (:func:`posecast.body.forecast.forecast`) and held, against the truth at ``n + h``,
    for each ``h`` of :data:`FORECAST_FRAMES` (ticks with a full history); and the
    stream's own pose at ``n + h`` there, the error of a perfect forecast of the stream
    (``bound_...``: no forecast of it gets under that)."""
    out: dict[str, m.Acc] = {}
    T = len(wp)
    quat = mat2quat(wm)
    for h in FORECAST_FRAMES:
        ms = round(h * 1000 / 60)
        # Ticks n whose emitted frame e = n - lag has SPAN frames before it and whose
        # truth n + h exists: e from SPAN to T - 1 - lag - h.
        e = np.arange(SPAN, T - lag - h)
        if len(e) == 0:
            continue
        window = e[:, None] + np.arange(-SPAN, 1)[None, :]  # (n, K)
        fp, _ = forecast(wp[window], quat[window], np.full(len(e), float(h)), fps)
        now = gt[e + lag + h]
        out[f"forecast_{ms}ms_mpjpe_cm"] = m.mpjpe(fp, now)
        out[f"hold_{ms}ms_mpjpe_cm"] = m.mpjpe(wp[e], now)
        out[f"bound_{ms}ms_mpjpe_cm"] = m.mpjpe(wp[e + h], now)
    return out


def _true_waist(fr: Frames) -> tuple[np.ndarray, np.ndarray]:
    """A clip's waist tracker on the true pelvis, ``(T, 3, 3)`` and ``(T, 3)`` float64."""
    root_mat = quat2mat(fr["tracker_quat"][:, TrackerSlot.WAIST].astype(np.float64))
    return root_mat, fr["tracker_pos"][:, TrackerSlot.WAIST].astype(np.float64)


def _decode(
    name: str,
    dec: Artifact,
    ae: Artifact | None,
    tr: Tracks,
    root_from_waist: bool,
    latent: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A single-sample variant's network over a clip, as the engine holds a decoded
    sample: rotations ``(T, 108)`` and contacts ``(T, 2)`` float32, and the pelvis
    ``(T, 3, 3)`` / ``(T, 3)`` float32 (:func:`~posecast.body.pelvis.pelvis_poses`)."""
    if name == "ae_ik":
        assert ae is not None
        rot, con = decode_ae(ae, tr.features)
        root = None
    else:
        rot, con, root = decode_cvae(dec, tr.features, np.zeros(latent, np.float32))
    root_out = None if root_from_waist or root is None else root.astype(np.float32)
    rootm = quat2mat(tr.quat[:, TrackerSlot.WAIST]).astype(np.float32)
    root_mat, root_pos, _ = pelvis_poses(tr.values, tr.quat, rootm, root_out, 1)
    rot32 = rot.reshape(len(rot), -1).astype(np.float32)
    return rot32, np.asarray(con, np.float32), root_mat, root_pos


def run_shown(
    passes: Passes,
    decoded: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    clips: Sequence[Tracks],
    cfg: EngineConfig,
    root_from_waist: bool,
    kinds: np.ndarray | None = None,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """What the engine streams of one decoded sample per clip (:func:`_decode`'s
    rotations, contacts and pelvis): :func:`~posecast.body.pipeline.show` frame by
    frame, every clip a row of one batch as the engine's players are, each carrying
    its own state from frame to frame, on ``passes`` (a backend's pool). The pelvis is
    smoothed with its neighbours' (a clip's first and last frames stand in for the
    missing one, as the engine's first frame does), and it is the decoder's guess
    unless ``root_from_waist``; ``kinds``: a tracker set's sites.

    Returns per clip world rotations ``(T, 19, 3, 3)`` and positions ``(T, 19, 3)``.
    """
    C = len(decoded)
    lengths = np.array([len(d[0]) for d in decoded])
    last = lengths - 1
    # Every clip's arrays padded to the longest with its last frame: (C, T, ...)
    T = int(lengths.max())

    def padded(arrays: list[np.ndarray]) -> np.ndarray:
        return np.stack([np.concatenate([a, a[-1:].repeat(T - len(a), 0)]) for a in arrays])

    rot, con, root_mat, root_pos = (padded([d[k] for d in decoded]) for k in range(4))
    tp, tq = padded([tr.values for tr in clips]), padded([tr.quat for tr in clips])
    smooth = cfg.pelvis_smoothing
    # Without a delay frame t stands in for t + 1, and a waist tracker's position is
    # frame t's own, as the engine's (online/engine/ring.py pelvis_neighbours).
    ahead = 1 if cfg.delay >= 1 else 0
    state = ShownState.zeros(C)
    out_pos = np.zeros((C, T, 19, 3), np.float32)
    out_rot = np.zeros((C, T, 19, 4), np.float32)
    for t in range(T):
        rows = np.flatnonzero(lengths > t)
        neighbours = None
        if smooth:
            at = np.concatenate(
                [np.full(len(rows), max(t - 1, 0)), np.minimum(t + ahead, last[rows])]
            )
            both = np.concatenate([rows, rows])
            E = len(rows)
            places = root_pos[both, at] if ahead or not root_from_waist else root_pos[both, t]
            neighbours = (root_mat[both, at].reshape(2, E, 3, 3), places.reshape(2, E, 3))
        batch = Decoded(
            rot[rows, t],
            con[rows, t],
            root_mat[rows, t],
            root_pos[rows, t],
            tp[rows, t],
            tq[rows, t],
            first=np.full(len(rows), t == 0),
            neighbours=neighbours,
            free=None if root_from_waist else np.ones(len(rows), np.bool_),
            kinds=None if kinds is None else np.broadcast_to(kinds, (len(rows), len(kinds))),
        )
        sub = ShownState.of([a[rows] for a in state.arrays()])
        shown = show(batch, sub, cfg, passes)
        for whole, part in zip(state.arrays(), sub.arrays(), strict=True):
            whole[rows] = part
        out_pos[rows, t], out_rot[rows, t] = shown.positions, shown.rotations
    return [
        (quat2mat(out_rot[c, :n].astype(np.float64)), out_pos[c, :n].astype(np.float64))
        for c, n in enumerate(lengths.tolist())
    ]


def run_ssi(
    backend: Backend,
    clips: Sequence[Tracks],
    cfg: EngineConfig,
    tracker_set: TrackerSet | None = None,
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """The full method: every clip's trackers as one player of one engine on
    ``backend`` (every player on ``tracker_set``, for the sites model), all stepped
    together.

    Returns per clip the emitted world rotations ``(T, 19, 3, 3)`` and positions
    ``(T, 19, 3)``, aligned with the input frames (the engine's delay, ``tau`` frames
    with ``delayed_emission``, undone by ``seq``), and the number of transitions.
    """
    engine = Engine(
        backend.decoder, backend.pool, cfg, capacity=len(clips), backend_name=backend.name
    )
    for i in range(len(clips)):
        engine.add_player(str(i), seed=i, tracker_set=tracker_set)
    out = [np.full((len(tr.values), 19, 3), np.nan, np.float32) for tr in clips]
    rots = [np.full((len(tr.values), 19, 4), np.nan, np.float32) for tr in clips]
    done: dict[int, int] = {}
    longest = max(len(tr.values) for tr in clips)
    for t in range(longest + cfg.delay):
        for i, tr in enumerate(clips):
            if t < len(tr.values):
                engine.push(str(i), TrackerFrame(t, tr.values[t], tr.quat[t]))
        for pose in engine.tick().poses:
            i = int(pose.player)
            if not pose.held and 0 <= pose.seq < len(out[i]):
                out[i][pose.seq] = pose.positions
                rots[i][pose.seq] = pose.rotations
        for i, tr in enumerate(clips):
            if i not in done and t + 1 >= len(tr.values) + cfg.delay:
                done[i] = engine.transitions(str(i))
                engine.remove_player(str(i))
    if any(np.isnan(o).any() for o in out):
        raise RuntimeError("the engine skipped frames")  # a bug, never bad data
    return [
        (quat2mat(r.astype(np.float64)), o.astype(np.float64), done[i])
        for i, (r, o) in enumerate(zip(rots, out, strict=True))
    ]


def format_table(report: dict[str, Any]) -> str:
    """The console table of ``posecast eval``: a metric per row, a variant per column
    (and the ground truth's own figures), so that the long metric names fit; a figure
    a variant does not have is ``-``. ``--json`` keeps the report itself."""
    columns = [(name, res) for name, res in report["variants"].items()]
    gt = report.get("ground_truth") or {}
    if gt:
        columns.append(("ground_truth", gt))
    rows = [(k, [res.get(k) for _, res in columns]) for k in METRIC_KEYS]
    rows.append(("seconds", [res.get("seconds") for _, res in columns]))

    def cell(x: float | None, digits: int) -> str:
        return "-" if x is None else f"{x:.{digits}f}"

    cells = [(k, [cell(x, 1 if k == "seconds" else 3) for x in xs]) for k, xs in rows]
    first = max(len("metric"), *(len(k) for k, _ in cells))
    widths = [
        max(len(name), *(len(row[i]) for _, row in cells)) for i, (name, _) in enumerate(columns)
    ]

    def line(label: str, texts: list[str]) -> str:
        return f"{label:<{first}}" + "".join(
            f"  {t:>{w}}" for t, w in zip(texts, widths, strict=True)
        )

    title = f"layout {report.get('layout', Layout.HMD3_WAIST)}"
    if report.get("backend"):
        title += f", SSI on backend {report['backend']}"
        k = report.get("kernels") or {}
        if k.get("isa"):
            title += f" ({k['isa']}, {k['precision']})"
    lines = [title, line("metric", [name for name, _ in columns])]
    lines += [line(k, row) for k, row in cells]
    return "\n".join(lines)
