"""Frozen-encoder artifact: f and φ after pretraining (ξ is discarded, paper IV-B end).

File content (``torch.save`` of plain containers, loadable with ``weights_only=True``)::

    {"kind": "omcrl-encoder", "format": 1, "meta": "<JSON>", "f": {name: tensor}, "phi": {name: tensor}}

``meta`` holds frame_stack, crop_from (the env image size), crop_to (= image_size of f), feature_dim,
proj_hidden, use_projection, method, dataset fingerprint and kit version.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch
from torch import nn

import omcrl
from omcrl.models.encoder import PixelEncoder, Projection
from omcrl.runs import verify_artifact
from omcrl.utils.io import atomic_save_torch, load_torch

ARTIFACT_KIND = "omcrl-encoder"
ARTIFACT_FORMAT = 1


class EncoderError(ValueError):
    """An encoder artifact is missing, malformed or does not fit the caller (message names file and field)."""


def encoder_meta(cfg: Any, dataset_fingerprint: str = "") -> dict:
    """JSON-able description of the encoder built from ``cfg`` (an :class:`omcrl.config.Config`)."""

    p = cfg.pretrain
    return {
        "frame_stack": int(cfg.env.frame_stack),
        "crop_from": int(p.crop_from),
        "crop_to": int(p.crop_to),
        "image_size": int(p.crop_to),
        "feature_dim": int(p.feature_dim),
        "proj_hidden": int(p.proj_hidden),
        "use_projection": bool(p.use_projection),
        "method": str(p.method),
        "dataset_fingerprint": dataset_fingerprint,
        "kit_version": omcrl.__version__,
    }


class FrozenEncoder(nn.Module):
    """z = φ(f(center_crop(h))): (B, 3L, H, W) → (B, d), eval mode, no trainable parameters.

    H may be ``crop_from`` (the env image size: center-cropped to ``crop_to`` inside) or ``crop_to`` already.
    Input on the 0–255 scale (uint8 or float). Gradients still flow to the *input* (e.g. for Grad-CAM).

    Attributes
    ----------
    feature_dim : d, output size (φ's output when ``use_projection``, else f's).
    frame_stack, crop_from, crop_to, meta
    """

    def __init__(self, meta: dict, f: PixelEncoder, phi: nn.Module) -> None:
        super().__init__()
        self.meta = dict(meta)
        self.f, self.phi = f, phi
        self.frame_stack = int(meta["frame_stack"])
        self.crop_from, self.crop_to = int(meta["crop_from"]), int(meta["crop_to"])
        self.feature_dim = int(meta["feature_dim"])
        self.freeze()

    def freeze(self) -> FrozenEncoder:
        for p in self.parameters():
            p.requires_grad_(False)
        return self.eval()

    def train(self, mode: bool = True) -> FrozenEncoder:  # stays in eval: nothing in it should adapt
        return super().train(False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        side = x.shape[-1]
        if side == self.crop_from and side != self.crop_to:
            o = (self.crop_from - self.crop_to) // 2
            x = x[..., o : o + self.crop_to, o : o + self.crop_to]
        elif side != self.crop_to:
            raise ValueError(
                f"encoder expects images of {self.crop_from} px (env) or {self.crop_to} px "
                f"(already cropped), got {tuple(x.shape)}"
            )
        return self.phi(self.f(x))


def build_encoder(meta: dict, seed: int | None = None) -> FrozenEncoder:
    """A frozen encoder with the architecture in ``meta`` and fresh random weights (baseline for probes)."""
    if seed is not None:
        torch.manual_seed(seed)
    f = PixelEncoder(int(meta["frame_stack"]), int(meta["crop_to"]), int(meta["feature_dim"]))
    d = int(meta["feature_dim"])
    phi = Projection(d, int(meta["proj_hidden"]), d) if meta["use_projection"] else nn.Identity()
    return FrozenEncoder(meta, f, phi)


def random_encoder(cfg: Any, seed: int = 0) -> FrozenEncoder:
    """Randomly initialised frozen encoder with the same configuration as a pretrained one from ``cfg``."""
    return build_encoder({**encoder_meta(cfg), "method": "random"}, seed=seed)


def _artifact(meta: dict, f: nn.Module, phi: nn.Module | None) -> dict:
    plain = lambda m: {k: v.detach().cpu().clone() for k, v in m.state_dict().items()}  # noqa: E731
    return {
        "kind": ARTIFACT_KIND,
        "format": ARTIFACT_FORMAT,
        "meta": json.dumps(meta, sort_keys=True),
        "f": plain(f),
        "phi": plain(phi) if (phi is not None and meta.get("use_projection")) else {},
    }


def encoder_payload(f: PixelEncoder, phi: nn.Module | None, cfg: Any, dataset_fingerprint: str = "") -> dict:
    """What ``encoder.pt`` holds for a freshly trained f (and φ when the configuration uses it): plain tensors and
    JSON meta (:func:`encoder_meta`)."""
    return _artifact(encoder_meta(cfg, dataset_fingerprint), f, phi)


def save_encoder(
    path: str | Path, f: PixelEncoder, phi: nn.Module | None, cfg: Any, dataset_fingerprint: str = ""
) -> Path:
    """Write the frozen-encoder artifact (:func:`encoder_payload`) atomically. Returns the path."""
    atomic_save_torch(encoder_payload(f, phi, cfg, dataset_fingerprint), path)
    return Path(path)


def load_encoder(path: str | Path, image_size: int | None = None, frame_stack: int | None = None) -> FrozenEncoder:
    """Load a frozen encoder; ``image_size`` (env image side) and ``frame_stack`` are checked when given.

    Returns an eval-mode module with ``requires_grad=False`` mapping (B, 3L, H, W) → (B, d).
    Raises :class:`EncoderError` naming the file and the mismatch.
    """
    p = Path(path)
    if not p.is_file():
        raise EncoderError(f"encoder {p}: file does not exist")
    verify_artifact(p, "encoder", "re-run its pretraining (python -m omcrl pretrain --method ...), which rebuilds it")
    return encoder_from_artifact(load_torch(p, "encoder artifact", EncoderError), str(p), image_size, frame_stack)


def encoder_from_artifact(
    obj: Any, source: str, image_size: int | None = None, frame_stack: int | None = None
) -> FrozenEncoder:
    """A frozen encoder from an artifact dict (as saved by :func:`save_encoder` or embedded in a policy file).

    ``source`` names where the dict came from in error messages; sizes are checked as in :func:`load_encoder`.
    """
    p = source
    if not isinstance(obj, dict) or obj.get("kind") != ARTIFACT_KIND:
        raise EncoderError(f"encoder {p}: not an omcrl encoder artifact (missing kind={ARTIFACT_KIND!r})")
    if obj.get("format") != ARTIFACT_FORMAT:
        raise EncoderError(f"encoder {p}: field 'format' expected {ARTIFACT_FORMAT}, got {obj.get('format')}")
    meta = json.loads(obj["meta"])
    for name, want, got in (
        ("image_size", image_size, meta["crop_from"]),
        ("frame_stack", frame_stack, meta["frame_stack"]),
    ):
        if want is not None and int(want) != int(got):
            raise EncoderError(
                f"encoder {p}: field '{name}' expected {int(want)} by the caller, the encoder was trained with {got}"
            )
    enc = build_encoder(meta)
    try:
        enc.f.load_state_dict(obj["f"])
        if meta["use_projection"]:
            enc.phi.load_state_dict(obj["phi"])
    except RuntimeError as e:
        raise EncoderError(f"encoder {p}: weights do not match the stored configuration ({e})") from None
    return enc.freeze()


def encoder_artifact(enc: FrozenEncoder) -> dict:
    """The artifact dict of a frozen encoder (plain tensors + JSON meta), e.g. to embed it in a policy file."""
    return _artifact(enc.meta, enc.f, enc.phi)
