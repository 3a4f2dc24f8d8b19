"""Grad-CAM of a visuomotor policy's action with respect to its encoder's last conv layer (paper VI-B, Fig. 13).

Grad-CAM (Selvaraju et al., 2017): with A (N, C, h, w) the activations of a conv layer and y (N,) a score of the
output, the map is ReLU(Σ_c w_c A_c) with w_c the spatial mean of ∂y/∂A_c, upsampled to the input's size. Here y
is a function of the policy's mean action (:data:`TARGETS`), the state part of the policy input is held at the
frame's own state, and the layer is the encoder's last conv block (after its ReLU).

The kit implements it itself rather than through the ``grad-cam`` package: that package imports torchvision,
and no torchvision build imports beside the CPU build of torch 2.13 used here
(docs/method.md, "Grad-CAM, the kit's own").

:func:`mass_share` turns a map into a number: the share of its mass on obstacle pixels, next to the share of the
image that obstacles cover (what a uniform map would give).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import nn

from omcrl.config import ConfigError

# Scores of the mean action a (N, 3) = (v_x, v_y, ω_z) in [-1, 1]: the evidence for its magnitude.
TARGETS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "all": lambda a: a.abs().sum(1),
    "forward": lambda a: a[:, 0].abs(),
    "lateral": lambda a: a[:, 1].abs(),
    "yaw": lambda a: a[:, 2].abs(),
}


def grad_cam(
    model: nn.Module, layer: nn.Module, x: torch.Tensor, score: Callable[[torch.Tensor], torch.Tensor]
) -> np.ndarray:
    """Grad-CAM maps of ``score(model(x))`` at ``layer``.

    Parameters
    ----------
    model : maps x (N, C, H, W) float to an output ``score`` reduces to (N,).
    layer : a module inside ``model`` whose output is a (N, K, h, w) feature map.
    x : the input batch (float; it need not require grad).
    score : output -> (N,) scores, one per sample (e.g. an entry of :data:`TARGETS`).

    Returns
    -------
    (N, H, W) float32 maps ≥ 0 at the input's resolution (bilinear upsampling), not normalised; all zero where
    no location raises the score.
    """
    store: dict[str, torch.Tensor] = {}

    def hook(_m: nn.Module, _i: Any, out: torch.Tensor) -> None:
        out.retain_grad()
        store["a"] = out

    handle = layer.register_forward_hook(hook)
    was_training = model.training
    model.eval()
    try:
        with torch.enable_grad():
            inp = x.detach().float().requires_grad_(True)  # frozen weights: the graph must start at the input
            s = score(model(inp))
            if s.dim() != 1 or s.shape[0] != x.shape[0]:
                raise ValueError(f"grad_cam: score must give one value per sample (N,), got {tuple(s.shape)}")
            s.sum().backward()
        a, g = store["a"], store["a"].grad
        if a.dim() != 4 or g is None:
            raise ValueError(f"grad_cam: layer output must be a (N, K, h, w) map, got {tuple(a.shape)}")
        w = g.mean(dim=(2, 3), keepdim=True)
        cam = torch.relu((w * a).sum(1, keepdim=True))
        cam = nn.functional.interpolate(cam, size=x.shape[-2:], mode="bilinear", align_corners=False)
        return cam[:, 0].detach().numpy().astype(np.float32)
    finally:
        handle.remove()
        model.train(was_training)


class PolicyImageModel(nn.Module):
    """A policy as a function of its image input alone: the centre crop it sees, stacks (N, 3L, c, c) on the
    0–255 scale (float) → mean action (N, 3).

    The state part of the policy's input is fixed to ``state`` (N, 12), the frames' own states. Works for
    policies on a frozen encoder (``student``: ours, CURL, ours-noOT) and end to end (``pixel``: PPO, NPE).
    ``conv_layer`` is the encoder's last conv block output (after its ReLU), where Grad-CAM is taken.
    """

    def __init__(self, policy: Any, state: torch.Tensor) -> None:
        super().__init__()
        self.agent = policy.agent
        kind = self.agent.features.kind
        if kind == "student":
            self.encoder = self.agent.features.encoder
            convs = self.encoder.f.convs
        elif kind == "pixel":
            self.encoder = self.agent.features.encoder
            convs = self.encoder.convs
        else:
            raise ConfigError(f"Grad-CAM needs a policy on camera images (ours, CURL, PPO, ...); got a {kind!r} policy")
        self.kind, self.state = kind, state
        self.conv_layer = convs[-1]
        self.crop = crop_side(policy)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.kind == "student":
            stored = {"x": torch.cat([self.encoder(x).float(), self.state], dim=1)}
        else:
            stored = {"rgb": x, "state": self.state}
        mean, _, _ = self.agent(stored)
        return mean


def policy_cam(policy: Any, stacks: np.ndarray, states: np.ndarray, target: str = "all", batch: int = 64) -> np.ndarray:
    """Grad-CAM of a policy's mean action on observation stacks.

    Parameters
    ----------
    policy : a loaded :class:`omcrl.rl.Policy` on camera images.
    stacks : (N, 3L, H, W) uint8 observation stacks; states : (N, 12) their state vectors.
    target : which action score (:data:`TARGETS`).

    Returns
    -------
    (N, c, c) float32 maps over the centre crop of c = :func:`crop_side` px that the encoder sees (crop masks
    the same way with :func:`center_crop`).
    """
    if target not in TARGETS:
        raise ConfigError(f"Grad-CAM target: got {target!r}, known targets are {list(TARGETS)}")
    c = crop_side(policy)
    out = []
    for i in range(0, len(stacks), batch):
        x = torch.from_numpy(center_crop(np.ascontiguousarray(stacks[i : i + batch]), c)).float()
        model = PolicyImageModel(policy, torch.as_tensor(states[i : i + batch], dtype=torch.float32))
        out.append(grad_cam(model, model.conv_layer, x, TARGETS[target]))
    return np.concatenate(out)


def crop_side(policy: Any) -> int:
    """The side (px) of the centre crop a camera policy's encoder sees."""
    feats = policy.agent.features
    if feats.kind not in ("student", "pixel"):
        raise ConfigError(
            f"Grad-CAM needs a policy on camera images (ours, CURL, PPO, ...); got a {feats.kind!r} policy"
        )
    return int(feats.encoder.crop_to) if feats.kind == "student" else int(feats.crop)


def center_crop(x: np.ndarray, side: int) -> np.ndarray:
    """(..., H, W) → (..., side, side), the centre of the image."""
    o = (x.shape[-1] - side) // 2
    return x[..., o : o + side, o : o + side]


def mass_share(cams: np.ndarray, masks: np.ndarray) -> dict[str, float]:
    """How much of the Grad-CAM mass lies on obstacle pixels.

    Parameters
    ----------
    cams : (N, H, W) maps ≥ 0; masks : (N, H, W) bool obstacle pixels of the same frames.

    Returns
    -------
    ``{"share": Σ cam·mask / Σ cam, the mean over frames with mass and obstacles, "obstacle_fraction": the mean
    share of pixels that are obstacles in those frames (a uniform map's share), "lift": share /
    obstacle_fraction, "frames": frames analysed, "frames_used": frames in the means}``. Frames without mass (no
    location raises the score) or without obstacle pixels are left out of the means.
    """
    cams, masks = np.asarray(cams, np.float64), np.asarray(masks, bool)
    if cams.shape != masks.shape:
        raise ValueError(f"mass_share: cams {cams.shape} and masks {masks.shape} differ")
    tot = cams.sum((1, 2))
    ok = (tot > 0) & masks.any((1, 2))
    n = len(cams)
    if not ok.any():
        nan = float("nan")
        return {"share": nan, "obstacle_fraction": nan, "lift": nan, "frames": n, "frames_used": 0}
    share = float(((cams * masks).sum((1, 2))[ok] / tot[ok]).mean())
    frac = float(masks[ok].mean())
    return {"share": share, "obstacle_fraction": frac, "lift": share / frac, "frames": n, "frames_used": int(ok.sum())}
