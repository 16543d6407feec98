"""The headset-only (``hmd3``) path of the engine and one batch per model.

These tests run a small randomly initialised hmd3 decoder exported through the real
export code (its pelvis outputs biased to stand the body under the head), so they test
the mechanics, not the trained model: the pelvis comes from the decoder, the waist
slot is never read, players of both layouts are stepped in their own batches. Each
runs on every backend (the ``backend`` fixture).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from posecast.body.upper_ik import ease_reach_clip, lean_root, reach_root
from posecast.geometry.rotations import quat2mat
from posecast.offline.evaluation.reconstruct import decode_cvae, pose_from_rotations
from posecast.offline.nets.cvae import CVAE, CVAEConfig
from posecast.offline.train.export import build_decoder, sidecar
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.artifact import Artifact, default_models_dir, load_artifact
from posecast.skeleton import Joint
from posecast.tracking.features import TrackerSlot
from posecast.tracking.layouts import Layout, pelvis_from_head, spec
from tests.online.engine.conftest import BackendLoader

WalkFrames = Callable[..., list[TrackerFrame]]


@pytest.fixture(scope="session")
def hmd3_models(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A models folder: the random hmd3 decoder beside the shipped anomaly AE."""
    torch.manual_seed(7)
    ls = spec(Layout.HMD3)
    cfg = CVAEConfig(n_features=ls.n_features, layout="hmd3", root_outputs=ls.root_outputs)
    model = CVAE(cfg)
    with torch.no_grad():  # pelvis upright (6D of the identity), 0.9 m up, under the head
        model.decoder.pose.bias[108:] = torch.tensor([1, 0, 0, 0, 1, 0, 0, 0.9, 0.0])
        model.decoder.pose.weight[108:] *= 0.01
    ckpt = {
        "model": model.state_dict(),
        "config": cfg.to_dict(),
        "norm": {
            "feat_mean": [0.0] * ls.n_features,
            "feat_std": [1.0] * ls.n_features,
            "pose_mean": [0.0] * 57,
            "pose_std": [1.0] * 57,
        },
    }
    folder = tmp_path_factory.mktemp("hmd3_model")
    onnx_model = build_decoder(ckpt)
    (folder / "cvae_decoder_hmd3.onnx").write_bytes(onnx_model.SerializeToString())
    meta = sidecar(ckpt, "cvae_decoder_hmd3", onnx_model)
    (folder / "cvae_decoder_hmd3.json").write_text(json.dumps(meta))
    for suffix in (".onnx", ".json"):
        shutil.copy(default_models_dir() / f"anomaly{suffix}", folder)
    return folder


@pytest.fixture(scope="session")
def hmd3_decoder(hmd3_models: Path) -> Artifact:
    return load_artifact("cvae_decoder_hmd3", hmd3_models)


@pytest.fixture(scope="session")
def hmd3_engine(backend: BackendLoader, hmd3_models: Path) -> Callable[..., Engine]:
    """``hmd3_engine(**EngineConfig fields)``: an engine on the random hmd3 decoder."""

    def make(**cfg: object) -> Engine:
        return backend.engine(Layout.HMD3, hmd3_models, **cfg)  # type: ignore[arg-type]

    return make


def _engine4(backend: BackendLoader, **cfg: object) -> Engine:
    return backend.engine(Layout.HMD3_WAIST, **cfg)  # type: ignore[arg-type]


def _offline(
    decoder: Artifact, frames: list[TrackerFrame]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The decoder's pose of ``frames`` at eps = 0, offline on ONNX Runtime: rotations
    ``(T, 108)``, and its pelvis (rotations, positions) out of the head frame."""
    pos = np.stack([f.pos for f in frames])
    quat = np.stack([f.quat for f in frames])
    feats = spec(Layout.HMD3).clip_features(pos, quat, 60.0).astype(np.float32)
    rot, _, root = decode_cvae(decoder, feats, np.zeros(30, np.float32))
    assert root is not None
    root_mat, root_pos = pelvis_from_head(root, pos[:, TrackerSlot.HEAD], quat[:, TrackerSlot.HEAD])
    return rot, root_mat, root_pos


def test_the_pelvis_comes_from_the_decoder_under_the_head(
    hmd3_decoder: Artifact, hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    """With one sample, no pelvis smoothing: the emitted pelvis is the decoder's pelvis
    output moved out of the head frame, as an offline decode on ONNX Runtime gives it
    (without the upper-body pass, which may move a guessed pelvis toward the headset)."""
    e = hmd3_engine(samples=1, pelvis_smoothing=False, upper_body_ik=False)
    e.add_player("a", seed=0)
    frames = walk_frames(0)[:30]
    got = []
    for f in frames:
        e.push("a", f)
        (pose,) = e.tick().poses
        got.append(pose.positions[Joint.PELVIS])
    _, _, want = _offline(hmd3_decoder, frames)
    np.testing.assert_allclose(np.stack(got), want, atol=1e-4)
    below = np.stack([f.pos[TrackerSlot.HEAD, 1] for f in frames]) - np.stack(got)[:, 1]
    assert np.all(below > 0.3)  # the body hangs from the head, not from a waist tracker


def test_a_guessed_pelvis_leans_toward_a_headset_lower_than_the_networks_head(
    hmd3_decoder: Artifact, hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    """The headset 15 cm lower and 20 cm further along the walk than the walk's head
    (a player bending over). With one sample and no pelvis smoothing, the streamed pelvis
    turns by the swing that aims the line from the decoder's pelvis to its head (FK of
    its pose, offline on ONNX Runtime) at the headset (``pelvis_lean``, the default),
    and keeps the decoder's rotation with ``pelvis_lean=False``."""
    frames = []
    for f in walk_frames(0)[:30]:
        pos = f.pos.copy()
        pos[TrackerSlot.HEAD] += [0.0, -0.15, 0.0]
        pos[TrackerSlot.HEAD, [0, 2]] += 0.2 * _heading(f.quat[TrackerSlot.HEAD])
        frames.append(TrackerFrame(f.seq, pos, f.quat))
    rot, root_mat, root_pos = _offline(hmd3_decoder, frames)
    _, fk = pose_from_rotations(rot.astype(np.float64), root_mat, root_pos)
    headset = np.stack([f.pos[TrackerSlot.HEAD] for f in frames])
    turn = lean_root(root_pos, fk[:, Joint.HEAD], headset)
    assert (
        np.degrees(np.arccos(np.clip((np.trace(turn, axis1=1, axis2=2) - 1) / 2, -1, 1))).min() > 5
    )
    for lean, want in ((True, turn @ root_mat), (False, root_mat)):
        e = hmd3_engine(samples=1, pelvis_smoothing=False, pelvis_lean=lean)
        e.add_player("a", seed=0)
        got = []
        for f in frames:
            e.push("a", f)
            (pose,) = e.tick().poses
            got.append(quat2mat(pose.rotations[Joint.PELVIS].astype(np.float64)))
        np.testing.assert_allclose(np.stack(got), want, atol=1e-4)


def _heading(q: np.ndarray) -> np.ndarray:
    """The horizontal unit direction ``(x, z)`` a headset of orientation ``q`` faces."""
    f = quat2mat(q) @ np.array([0.0, 0.0, 1.0])
    return f[[0, 2]] / np.linalg.norm(f[[0, 2]])


def test_a_guessed_pelvis_follows_a_controller_held_out_of_reach(
    hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    """The left controller held 40 cm further out to the left than the walk's hand
    (beyond the arm), the headset 20 cm lower (the random decoder stands its pelvis
    0.9 m up, under the head, whose spine then reaches the headset): with
    ``hand_reach`` (the default) the streamed body moves toward it horizontally
    before its feet are planted, and the hand ends nearer the controller (on average:
    the random decoder's arms are anywhere); with ``hand_reach=False`` the pelvis is
    where the head alone puts it."""
    frames, left = [], []
    for f in walk_frames(0)[:40]:
        pos = f.pos.copy()
        out = pos[TrackerSlot.LEFT_HAND] - pos[TrackerSlot.RIGHT_HAND]
        out[1] = 0.0
        out /= np.linalg.norm(out)
        pos[TrackerSlot.LEFT_HAND] += 0.4 * out
        pos[TrackerSlot.HEAD, 1] -= 0.2  # within the spine's reach of the decoder's pelvis
        frames.append(TrackerFrame(f.seq, pos, f.quat))
        left.append(out)
    by_seq = {f.seq: (f, d) for f, d in zip(frames, left, strict=True)}
    pelvis, miss = {}, {}
    for reach in (True, False):
        # Without the lean, which may already turn this random decoder's shoulder
        # toward the far controller, and the torso's span (the next test): the reach
        # alone.
        e = hmd3_engine(
            samples=4,
            lookahead=2,
            delayed_emission=True,
            hand_reach=reach,
            pelvis_lean=False,
            torso_span=False,
        )
        e.add_player("a", seed=0)
        poses = []
        for f in frames:
            e.push("a", f)
            poses += e.tick().poses
        assert len(poses) == len(frames) - 2
        pelvis[reach] = np.stack([p.positions[Joint.PELVIS] for p in poses])
        gap = np.stack(
            [
                by_seq[p.seq][0].pos[TrackerSlot.LEFT_HAND] - p.positions[Joint.LEFT_HAND]
                for p in poses
            ]
        )
        miss[reach] = np.linalg.norm(gap[:, [0, 2]], axis=-1)  # horizontally
    toward = np.stack([by_seq[s][1] for s in range(len(frames) - 2)])
    moved = pelvis[True] - pelvis[False]
    assert np.einsum("ei,ei->e", moved, toward).min() > 0.05
    np.testing.assert_allclose(moved[:, 1], 0.0, atol=5e-3)  # horizontally (eased: 2 mm)
    assert miss[False].min() > 0.1
    assert miss[True].mean() < miss[False].mean() - 0.05


def test_a_guessed_body_keeps_the_networks_torso_to_a_headset_under_its_head(
    hmd3_decoder: Artifact, hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    """The headset 1.2 m lower than the walk's head, under the head of the random decoder
    (whose pelvis stands 0.9 m up and whose spine hangs): one sample, no pelvis smoothing,
    no lean. With ``torso_span`` (the default) the streamed body is moved, against
    ``torso_span=False``, by what ``reach_root`` adds for the torso's span on the
    decoder's pose (FK, offline on ONNX Runtime), eased like the reach: down, the
    headset being nearer the spine than the network's head; the arithmetic is
    ``test_upper_ik``'s."""
    frames = []
    for f in walk_frames(0)[:40]:
        pos = f.pos.copy()
        pos[TrackerSlot.HEAD, 1] -= 1.2
        frames.append(TrackerFrame(f.seq, pos, f.quat))
    rot, root_mat, root_pos = _offline(hmd3_decoder, frames)
    _, fk = pose_from_rotations(rot.astype(np.float64), root_mat, root_pos)
    tp = np.stack([f.pos for f in frames])
    above = fk[:, Joint.HEAD, 1] - tp[:, TrackerSlot.HEAD, 1]
    assert above.min() > 0.05  # the precondition: the decoder's head over the headset
    want = ease_reach_clip(reach_root(fk, tp)) - ease_reach_clip(reach_root(fk, tp, span=0.0))
    assert want[:, 1].max() < -0.05
    pelvis = {}
    for span in (True, False):
        e = hmd3_engine(samples=1, pelvis_smoothing=False, pelvis_lean=False, torso_span=span)
        e.add_player("a", seed=0)
        got = []
        for f in frames:
            e.push("a", f)
            (pose,) = e.tick().poses
            got.append(pose.positions[Joint.PELVIS])
        pelvis[span] = np.stack(got)
    moved = pelvis[True] - pelvis[False]
    assert np.all(moved[:, 1] < 0.0)
    np.testing.assert_allclose(moved, want, atol=0.01)


def test_a_players_eased_reach_is_its_own(
    hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    """Two headset-only players in one engine, one holding a controller out of reach
    (its pelvis moves, eased frame by frame): the other streams what it streams alone,
    so the eased move is kept per player."""
    frames = walk_frames(1)[:30]
    far = []
    for f in frames:
        pos = f.pos.copy()
        pos[TrackerSlot.HEAD, 1] -= 0.2
        out = pos[TrackerSlot.LEFT_HAND] - pos[TrackerSlot.RIGHT_HAND]
        out[1] = 0.0
        pos[TrackerSlot.LEFT_HAND] += 0.4 * out / np.linalg.norm(out)
        far.append(TrackerFrame(f.seq, pos, f.quat))
    both, alone = (
        hmd3_engine(samples=4, lookahead=2, delayed_emission=True),
        hmd3_engine(samples=4, lookahead=2, delayed_emission=True),
    )
    both.add_player("reach", seed=1)
    for e in (both, alone):
        e.add_player("calm", seed=2)
    got: dict[str, list[np.ndarray]] = {"both": [], "alone": []}
    for f, g in zip(frames, far, strict=True):
        both.push("reach", g)
        both.push("calm", f)
        alone.push("calm", f)
        got["both"] += [p.positions for p in both.tick().poses if p.player == "calm"]
        got["alone"] += [p.positions for p in alone.tick().poses]
    assert len(got["both"]) == len(frames) - 2
    # (within float32 rounding: a backend may round a batch of two differently)
    np.testing.assert_allclose(np.stack(got["both"]), np.stack(got["alone"]), atol=1e-5)


def test_the_waist_slot_is_never_read(
    hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    runs = []
    for waist in (None, np.array([1e5, -3.0, 7.0])):
        e = hmd3_engine(samples=4, lookahead=2, delayed_emission=True)
        e.add_player("a", seed=1)
        out = []
        for f in walk_frames(1)[:20]:
            if waist is not None:
                pos, quat = f.pos.copy(), f.quat.copy()
                pos[TrackerSlot.WAIST], quat[TrackerSlot.WAIST] = waist, [0.0, 0.0, 0.0, 0.0]
                f = TrackerFrame(f.seq, pos, quat)
            e.push("a", f)
            out += [p.positions for p in e.tick().poses]
        runs.append(np.stack(out))
    assert np.isfinite(runs[1]).all()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_each_model_steps_its_own_players_in_one_batch(
    backend: BackendLoader, hmd3_engine: Callable[..., Engine], walk_frames: WalkFrames
) -> None:
    """Two layouts in one MultiEngine: each player is in its layout's engine, both
    emit every tick, and a player's poses equal those of an engine of its own."""
    multi = MultiEngine(
        {
            "hmd3+waist": _engine4(backend, samples=4, lookahead=2, delayed_emission=True),
            "hmd3": hmd3_engine(samples=4, lookahead=2, delayed_emission=True),
        }
    )
    assert multi.backends == {"hmd3+waist": backend.name, "hmd3": backend.name}
    multi.add_player("four", 11, "hmd3+waist")
    multi.add_player("three", 12, "hmd3")
    multi.add_player("three-b", 13, "hmd3")
    assert multi.counts() == {"hmd3+waist": 1, "hmd3": 2} and multi.player_count == 3
    alone = hmd3_engine(samples=4, lookahead=2, delayed_emission=True)
    alone.add_player("three", 12)
    frames = walk_frames(2)[:15]
    seen: dict[str, int] = {}
    for f in frames:
        for p in ("four", "three", "three-b"):
            multi.push(p, f)
        alone.push("three", f)
        res = multi.tick()
        for pose in res.poses:
            seen[pose.player] = seen.get(pose.player, 0) + 1
        mine = {p.player: p for p in res.poses}
        for pose in alone.tick().poses:
            # To float32 rounding: a backend may block its matrix products by batch size.
            np.testing.assert_allclose(mine["three"].positions, pose.positions, atol=1e-5)
    assert seen == {"four": 13, "three": 13, "three-b": 13}  # 15 frames, tau = 2
    multi.remove_player("three")
    assert multi.counts() == {"hmd3+waist": 1, "hmd3": 1}
    with pytest.raises(ValueError, match="already"):
        multi.add_player("four", 1, "hmd3")


def test_a_multi_engine_refuses_what_it_cannot_serve(
    backend: BackendLoader, hmd3_engine: Callable[..., Engine]
) -> None:
    only4 = MultiEngine({"hmd3+waist": _engine4(backend, samples=2)})
    with pytest.raises(ValueError, match="not served"):
        only4.add_player("x", 1, "hmd3")
    with pytest.raises(ValueError, match="runs a hmd3 model"):
        MultiEngine({"hmd3+waist": hmd3_engine(samples=2)})
    with pytest.raises(ValueError):
        MultiEngine({})


def test_the_hmd3_sidecar_must_match_its_features(hmd3_decoder: Artifact, tmp_path: Path) -> None:
    from posecast.errors import ModelError

    meta = dict(hmd3_decoder.meta)
    meta["layout"] = "hmd3+waist"  # 36 hmd3 feature names under the 4-point layout
    (tmp_path / "m.json").write_text(json.dumps(meta))
    (tmp_path / "m.onnx").write_bytes(b"")
    with pytest.raises(ModelError, match="feature layout"):
        load_artifact("m", tmp_path)
    meta["layout"] = "hmd5"
    (tmp_path / "m.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match="unknown tracker layout"):
        load_artifact("m", tmp_path)
