"""The torch backend (online.inference.torch_backend): its decoder, rebuilt from the ONNX
file's weights, against ONNX Runtime on the shipped decoders, and through the whole engine."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.dataset.frames import derive_frames
from posecast.offline.motion.synthetic import walk_clip
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import PoseOut, TrackerFrame
from posecast.online.inference.auto import load_backend
from posecast.online.inference.loader import load_engine
from posecast.tracking.layouts import Layout, spec

pytest.importorskip("torch")
pytest.importorskip("onnx")


@pytest.mark.parametrize("layout", list(Layout))
@pytest.mark.parametrize("group", [1, 4])
def test_the_torch_decoder_matches_onnx_runtime(layout: Layout, group: int) -> None:
    """One step on random features, latents and hidden states (``G`` feature rows, each
    shared by ``group`` decoded rows): every output within 1e-5 of ONNX Runtime's."""
    onnx, torch = load_backend("onnx", layout), load_backend("torch", layout)
    assert (onnx.name, torch.name) == ("onnx", "torch")
    dec, ref = torch.decoder, onnx.decoder
    assert dec.cache_width == ref.cache_width and dec.meta == ref.meta
    rng = np.random.default_rng(7)
    G, F, H = 16, spec(layout).n_features, int(ref.meta["model_config"]["hidden"])
    R = G * group
    # Raw features whose normalised values are standard normal, as the decoder sees them
    # (a near-constant feature's std is 1 mm: raw N(0, 1) would be 1000 sigma out).
    norm = ref.meta["normalisation"]
    z = rng.normal(size=(G, F))
    features = (np.asarray(norm["feat_mean"]) + z * np.asarray(norm["feat_std"])).astype(np.float32)
    eps = rng.normal(size=(R, int(ref.meta["model_config"]["latent"]))).astype(np.float32)
    h = np.tanh(rng.normal(size=(R, H))).astype(np.float32)
    widths = {"rotations": 108, "contacts": 2, "h_out": H}
    if spec(layout).predicts_root:
        widths["root"] = spec(layout).root_outputs
    outs = []
    for d in (ref, dec):
        out = {k: np.full((R, w), np.nan, np.float32) for k, w in widths.items()}
        d.step(features, group, d.cache_latents(eps), h, out)
        outs.append(out)
    for name in widths:
        np.testing.assert_allclose(outs[1][name], outs[0][name], atol=1e-5, rtol=0, err_msg=name)


def _walk(seed: int) -> list[TrackerFrame]:
    w = derive_frames(walk_clip(seconds=2.0, fps=60.0, seed=seed))
    pos, quat = w["tracker_pos"].astype(np.float64), w["tracker_quat"].astype(np.float64)
    return [TrackerFrame(i, p, q) for i, (p, q) in enumerate(zip(pos, quat, strict=True))]


def _run(engine: Engine, ticks: int, players: int) -> list[list[PoseOut]]:
    walks = [_walk(p) for p in range(players)]
    for p in range(players):
        engine.add_player(f"p{p}", seed=10 + p)
    out: list[list[PoseOut]] = [[] for _ in range(players)]
    for t in range(ticks):
        for p in range(players):
            engine.push(f"p{p}", walks[p][t % len(walks[p])])
        for pose in engine.tick().poses:
            out[int(pose.player[1:])].append(pose)
    return out


@pytest.mark.parametrize("layout", [Layout.HMD3_WAIST, Layout.HMD3])  # sites: test_sites_engine
def test_an_engine_on_torch_emits_what_it_emits_on_onnx(layout: Layout) -> None:
    """120 ticks, 3 players, 16 samples each with the default selector: the same samples
    and transitions, poses within 1e-4 m."""
    cfg = EngineConfig(samples=16)  # as served: every pose at its own frame's tick
    runs = [_run(load_engine(cfg, layout=layout, backend=b), 120, 3) for b in ("onnx", "torch")]
    for ref, got in zip(*runs, strict=True):
        assert len(ref) == len(got) == 120
        assert [(p.seq, p.sample, p.transitioning) for p in got] == [
            (p.seq, p.sample, p.transitioning) for p in ref
        ]
        for name in ("positions", "rotations", "contacts"):
            np.testing.assert_allclose(
                np.array([getattr(p, name) for p in got]),
                np.array([getattr(p, name) for p in ref]),
                atol=1e-4,
                rtol=0,
                err_msg=name,
            )
