"""Conditional VAE with GRUs (paper Sec. 3.1 and 4.2), plus its deterministic AE ablation.

The decoder (:class:`CVAEDecoder`), per frame ``t`` (what serving runs, with ``z = eps``)::

    f_t  = relu(W_in [x_t, z_t] + b)          # (B, 54) -> (B, 128)
    h_t  = GRU(f_t, h_{t-1})                  # (B, 128)
    r_t  = W_pose relu(h_t) + b               # (B, 108) = 18 joints x 6D
    c_t  = sigmoid(W_contact relu(h_t) + b)   # (B, 2) left, right foot

The paper's Sec. 4.2 says the pose head has "54 outputs", but Sec. 3 defines
``r_t`` in R^(18x6) = 108; 54 is the decoder's *input* size (24 + 30). posecast's pose
head has 108 outputs (see docs/skeleton.md).

Headset-only variant (``layout="hmd3"``, ``root_outputs=9``): the features are the 36
head-frame values of :func:`posecast.tracking.features.hmd3_features` and the pose head has 9
more outputs, the pelvis rotation (6D) and position (metres), in the head's yaw frame.

Encoder: the paper lists a 24-input encoder that sees only the trackers. A recognition
network that never sees the pose gives the latent nothing to explain, so ``z`` can only
act as noise the decoder learns to ignore. posecast's encoder also reads the target pose
(the 57 character-frame joint positions), as in Sohn et al.'s CVAE that the paper
builds on; ``CVAEConfig(encoder_sees_pose=False)`` restores the literal 24-input
encoder. Only the decoder runs at serving time, so this choice does not change the
exported artifact's interface.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from posecast.tracking.layouts import Layout


@dataclass(frozen=True)
class CVAEConfig:
    n_features: int = 24  # 4 trackers x (position, velocity)
    n_pose: int = 57  # 19 joints x 3, character frame (encoder input only)
    latent: int = 30
    hidden: int = 128
    n_rot: int = 18
    deterministic: bool = False  # the AE ablation: mu/sigma replaced by one FC layer
    encoder_sees_pose: bool = True
    layout: str = Layout.HMD3_WAIST.value  # stored as its string in the checkpoint
    root_outputs: int = 0  # 9 when the decoder predicts the pelvis pose (layout hmd3)

    def __post_init__(self) -> None:
        if self.deterministic and self.encoder_sees_pose:
            # The AE runs its encoder at serving time, when no pose exists yet.
            raise ValueError("the deterministic AE's encoder cannot see the pose")

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


class Encoder(nn.Module):
    def __init__(self, cfg: CVAEConfig) -> None:
        super().__init__()
        n_in = cfg.n_features + (cfg.n_pose if cfg.encoder_sees_pose else 0)
        self.fc = nn.Linear(n_in, cfg.hidden)
        self.gru = nn.GRU(cfg.hidden, cfg.hidden, batch_first=True)
        if cfg.deterministic:
            self.z = nn.Linear(cfg.hidden, cfg.latent)
        else:
            self.mu = nn.Linear(cfg.hidden, cfg.latent)
            self.logvar = nn.Linear(cfg.hidden, cfg.latent)
        self.cfg = cfg

    def forward(
        self, x: torch.Tensor, h0: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """``x (B, T, n_in)`` -> ``(mu or z (B, T, L), logvar or None, h_T (1, B, H))``."""
        f = torch.relu(self.fc(x))  # (B, T, H)
        h, hT = self.gru(f, h0)  # (B, T, H)
        if self.cfg.deterministic:
            return self.z(h), None, hT
        return self.mu(h), self.logvar(h), hT


class CVAEDecoder(nn.Module):
    def __init__(self, cfg: CVAEConfig) -> None:
        super().__init__()
        self.fc = nn.Linear(cfg.n_features + cfg.latent, cfg.hidden)
        self.gru = nn.GRU(cfg.hidden, cfg.hidden, batch_first=True)
        # For a model that predicts the pelvis, its 6D rotation and position (head
        # frame) follow the 108 joint-rotation outputs in the same head.
        self.pose = nn.Linear(cfg.hidden, cfg.n_rot * 6 + cfg.root_outputs)
        self.contact = nn.Linear(cfg.hidden, 2)
        self.cfg = cfg

    def forward(
        self, x: torch.Tensor, z: torch.Tensor, h0: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Whole sequence: ``x (B, T, 24)``, ``z (B, T, 30)`` ->
        ``(rot (B, T, 108 [+ 9]), contact logits (B, T, 2), h_T (1, B, 128))``."""
        f = torch.relu(self.fc(torch.cat([x, z], dim=-1)))  # (B, T, 128)
        h, hT = self.gru(f, h0)  # (B, T, 128)
        a = torch.relu(h)
        return self.pose(a), self.contact(a), hT

    def step(
        self, x: torch.Tensor, z: torch.Tensor, h: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One frame with the GRU math written out, as exported to ONNX.

        ``x (B, 24)``, ``z (B, 30)``, ``h (B, 128)`` ->
        ``(rot (B, 108), contact probabilities (B, 2), h' (B, 128))``.
        """
        f = torch.relu(self.fc(torch.cat([x, z], dim=-1)))  # (B, 128)
        g = self.gru
        w_ih, b_ih = g.weight_ih_l0, g.bias_ih_l0
        w_hh, b_hh = g.weight_hh_l0, g.bias_hh_l0
        assert isinstance(w_ih, torch.Tensor) and isinstance(b_ih, torch.Tensor)
        assert isinstance(w_hh, torch.Tensor) and isinstance(b_hh, torch.Tensor)
        gi = f @ w_ih.T + b_ih  # (B, 384): r, u, n
        gh = h @ w_hh.T + b_hh  # (B, 384)
        H = self.cfg.hidden
        r = torch.sigmoid(gi[:, :H] + gh[:, :H])
        u = torch.sigmoid(gi[:, H : 2 * H] + gh[:, H : 2 * H])
        n = torch.tanh(gi[:, 2 * H :] + r * gh[:, 2 * H :])
        h_new = n + u * (h - n)  # = (1 - u) * n + u * h
        a = torch.relu(h_new)
        return self.pose(a), torch.sigmoid(self.contact(a)), h_new


class CVAE(nn.Module):
    """Encoder plus decoder; ``forward`` is the training pass over windows."""

    def __init__(self, cfg: CVAEConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = Encoder(cfg)
        self.decoder = CVAEDecoder(cfg)

    def forward(
        self, x: torch.Tensor, pose: torch.Tensor | None = None, sample: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``x (B, T, 24)`` normalised features, ``pose (B, T, 57)`` normalised local
        positions (used when the encoder sees the pose) ->
        ``(rot (B, T, 108), contact logits (B, T, 2), kl per frame (B, T))``."""
        if self.cfg.encoder_sees_pose:
            if pose is None:
                raise ValueError("this CVAE's encoder needs the pose")
            enc_in = torch.cat([x, pose], dim=-1)
        else:
            enc_in = x
        mu, logvar, _ = self.encoder(enc_in)
        if logvar is None:
            z = mu
            kl = torch.zeros(x.shape[:2], device=x.device)
        else:
            std = torch.exp(0.5 * logvar)
            z = mu + std * torch.randn_like(std) if sample else mu
            kl = 0.5 * (mu.pow(2) + logvar.exp() - 1.0 - logvar).sum(dim=-1)  # (B, T)
        rot, contact_logits, _ = self.decoder(x, z)
        return rot, contact_logits, kl
