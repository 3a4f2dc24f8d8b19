"""Feature extractors: what a policy's heads see, by observation kind (a registry, not an ``if`` chain).

A :class:`FeatureExtractor` turns a *batched* vector-env observation into

* ``preprocess(obs) -> dict[str, Tensor]``: what the rollout buffer stores per step. Frozen parts (a pretrained
  pixel encoder) run here, once per env step, batched across envs, under ``no_grad``; trainable parts (the
  oracle's depth encoder, the end-to-end pixel encoder) store their raw input so PPO epochs can back-propagate
  through them.
* ``forward(stored) -> Tensor (B, F)``: the feature vector the actor and critic see.
* ``spec() -> dict``: JSON-able; :func:`build_features` rebuilds the extractor from it (policy files).

Kinds (``FEATURE_KINDS``):

* ``identity`` — plain Box observations, flattened;
* ``oracle`` — [DepthEncoder(depth stack), v, ω, θ, Δp ∈ R⁶], depth encoder trained with the policy (IV-C);
* ``student`` — [frozen f(rgb stack), v, ω, θ, Δp_goal], f pretrained (OMC, CURL) and loaded from a file;
* ``pixel`` — [f(rgb stack), v, ω, θ, Δp_goal] with f of the same architecture trained end to end with the
  policy (the PPO and NPE baselines, V-C).

A new kind is a subclass with a ``kind`` name, registered with :func:`register_feature_kind`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from omcrl.envs.observation import KINEMATICS, ORACLE_LOW_DIM, STATE_DIM
from omcrl.models.artifact import encoder_from_artifact, load_encoder
from omcrl.models.encoder import DepthEncoder, PixelEncoder


class CheckpointError(RuntimeError):
    """A checkpoint (policy, oracle or encoder) is missing, unreadable or does not fit the environment."""


FEATURE_KINDS: dict[str, Callable[[dict], FeatureExtractor]] = {}


def register_feature_kind(kind: str, from_spec: Callable[[dict], FeatureExtractor]) -> None:
    """Make ``build_features({"kind": kind, ...})`` call ``from_spec(spec)``."""
    FEATURE_KINDS[kind] = from_spec


def build_features(spec: dict) -> FeatureExtractor:
    """Rebuild a feature extractor from its ``spec()``; raise CheckpointError for an unknown kind."""
    kind = spec.get("kind")
    if kind not in FEATURE_KINDS:
        raise CheckpointError(f"unknown feature kind {kind!r}; known kinds: {sorted(FEATURE_KINDS)}")
    return FEATURE_KINDS[kind](spec)


def space_shapes(space: Any) -> dict[str, list[int]]:
    """``{key: shape}`` of a (Dict) observation space; a Box gives ``{"obs": shape}``."""
    if hasattr(space, "spaces") and isinstance(space.spaces, dict):
        return {k: list(s.shape) for k, s in space.spaces.items()}
    return {"obs": list(space.shape)}


def load_frozen_encoder(path: str | Path, image_size: int, frame_stack: int) -> nn.Module:
    """Load a pretrained frozen encoder, turning every failure into a CheckpointError naming the file."""

    p = Path(path)
    if not p.exists():
        raise CheckpointError(f"encoder checkpoint {p} does not exist (run the pretraining stage first)")
    try:
        enc = load_encoder(p, image_size, frame_stack)
    except Exception as e:
        raise CheckpointError(
            f"encoder checkpoint {p} cannot be loaded for image_size={image_size}, frame_stack={frame_stack}: {e}"
        ) from e
    enc.eval()
    for prm in enc.parameters():
        prm.requires_grad_(False)
    return enc


def _center_crop(x: torch.Tensor, size: int) -> torch.Tensor:
    """(..., H, W) -> (..., size, size), the centre of the image (no-op when already that size)."""
    side = x.shape[-1]
    if side == size:
        return x
    o = (side - size) // 2
    return x[..., o : o + size, o : o + size]


class FeatureExtractor(nn.Module):
    """Base class: batched observation -> stored tensors -> feature vector of size ``out_dim``."""

    out_dim: int
    kind: str = "base"

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:  # pragma: no cover - interface
        raise NotImplementedError

    def spec(self) -> dict:
        """JSON-able description used to rebuild the extractor from a checkpoint."""
        return {"kind": self.kind, "out_dim": self.out_dim}


class IdentityFeatures(FeatureExtractor):
    """Feature = flattened Box observation. ``obs``: (B, *obs_shape) -> stored ``x`` (B, F) float32."""

    kind = "identity"

    def __init__(self, obs_dim: int) -> None:
        super().__init__()
        self.out_dim = int(obs_dim)

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        x = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        return {"x": x.reshape(x.shape[0], -1)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        return stored["x"]

    def spec(self) -> dict:
        return {"kind": self.kind, "out_dim": self.out_dim, "obs_dim": self.out_dim}


class OracleFeatures(FeatureExtractor):
    """Oracle feature [DepthEncoder(depth), v, ω, θ, Δp_obstacle, Δp_goal] (paper Eq. 5-6).

    ``obs["depth"]`` (B, L, H, W) float32 metres is stored as float16 (halves buffer memory; 0.01 m
    resolution at 20 m is far below what the encoder resolves). ``low`` = state[:, KINEMATICS] (v, ω, θ) ++
    privileged (6,) -> (B, 15) (:mod:`omcrl.envs.observation`). The depth encoder is trained with the policy, so
    ``forward`` runs it on every minibatch.
    """

    kind = "oracle"

    def __init__(self, depth_encoder: nn.Module, depth_dim: int, encoder_kwargs: dict | None = None) -> None:
        super().__init__()
        self.depth_encoder = depth_encoder
        self.depth_dim = int(depth_dim)
        self.encoder_kwargs = dict(encoder_kwargs or {})
        self.out_dim = self.depth_dim + ORACLE_LOW_DIM

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        depth = torch.as_tensor(np.asarray(obs["depth"]), dtype=torch.float16)
        low = np.concatenate([np.asarray(obs["state"])[:, KINEMATICS], np.asarray(obs["privileged"])], axis=1)
        return {"depth": depth, "low": torch.as_tensor(low, dtype=torch.float32)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        z = self.depth_encoder(stored["depth"].float())
        return torch.cat([z, stored["low"]], dim=1)

    def spec(self) -> dict:
        return {
            "kind": self.kind,
            "out_dim": self.out_dim,
            "depth_dim": self.depth_dim,
            "encoder_kwargs": self.encoder_kwargs,
        }


class StudentFeatures(FeatureExtractor):
    """Student feature [f(rgb stack), v, ω, θ, Δp_goal] with a frozen pretrained encoder f (paper IV-C).

    ``obs["rgb"]`` (B, L, 3, H, W) uint8 is reshaped to (B, 3L, H, W) and encoded once per env step in
    ``preprocess`` (no grad); the buffer stores only ``x`` (B, d + 12). The encoder is deliberately *not* a
    registered submodule: it is not optimised and not saved in policy checkpoints (they record its path
    instead).
    """

    kind = "student"

    def __init__(
        self,
        encoder: nn.Module,
        enc_dim: int,
        encoder_path: str = "",
        image_size: int = 0,
        frame_stack: int = 0,
    ) -> None:
        super().__init__()
        self.__dict__["encoder"] = encoder  # bypass nn.Module registration on purpose (frozen, external)
        self.enc_dim = int(enc_dim)
        self.encoder_path = str(encoder_path)
        self.image_size, self.frame_stack = int(image_size), int(frame_stack)
        self.out_dim = self.enc_dim + STATE_DIM

    def _apply(self, fn: Any, *args: Any, **kwargs: Any) -> StudentFeatures:
        # ``.to(device)`` on the policy must move the frozen encoder too, though it is not a submodule.
        self.encoder._apply(fn, *args, **kwargs)
        return super()._apply(fn, *args, **kwargs)

    @torch.no_grad()
    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        """The encoder runs on its own device (the policy's); ``x`` comes back on that device."""
        # An encoder without parameters (e.g. a stand-in that returns fixed features) runs on the CPU.
        device = next(self.encoder.parameters(), torch.empty(0)).device
        rgb = torch.as_tensor(np.asarray(obs["rgb"])).to(device)
        b = rgb.shape[0]
        z = self.encoder(rgb.reshape(b, -1, rgb.shape[-2], rgb.shape[-1])).float()
        state = torch.as_tensor(np.asarray(obs["state"]), dtype=torch.float32).to(device)
        return {"x": torch.cat([z.reshape(b, -1), state], dim=1)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        return stored["x"]

    def spec(self) -> dict:
        return {
            "kind": self.kind,
            "out_dim": self.out_dim,
            "enc_dim": self.enc_dim,
            "encoder_path": self.encoder_path,
            "image_size": self.image_size,
            "frame_stack": self.frame_stack,
        }


class PixelFeatures(FeatureExtractor):
    """End-to-end feature [f(rgb stack), v, ω, θ, Δp_goal] with f trained jointly with the policy (V-C).

    f is a :class:`omcrl.models.PixelEncoder` of the same architecture as the pretrained encoder (paper V-D:
    "all baselines adopt the same DNN architecture as f_θ"), fed the same centre crop ``crop`` px of the env's
    ``image_size`` px frames that the frozen encoder sees at evaluation, so every method gets the same pixels.
    ``obs["rgb"]`` (B, L, 3, H, W) uint8 is stored cropped as (B, 3L, crop, crop) uint8 (a quarter of float
    memory); ``forward`` runs f on every minibatch so PPO's gradients reach it. Its weights are part of the
    policy file.
    """

    kind = "pixel"

    def __init__(self, frame_stack: int, image_size: int, crop: int, feature_dim: int) -> None:
        super().__init__()

        self.frame_stack, self.image_size, self.crop = int(frame_stack), int(image_size), int(crop)
        self.feature_dim = int(feature_dim)
        self.encoder = PixelEncoder(self.frame_stack, self.crop, self.feature_dim)
        self.out_dim = self.feature_dim + STATE_DIM

    def preprocess(self, obs: Any) -> dict[str, torch.Tensor]:
        rgb = torch.as_tensor(np.asarray(obs["rgb"]))
        b = rgb.shape[0]
        img = _center_crop(rgb.reshape(b, -1, rgb.shape[-2], rgb.shape[-1]), self.crop).contiguous()
        return {"rgb": img, "state": torch.as_tensor(np.asarray(obs["state"]), dtype=torch.float32)}

    def forward(self, stored: dict[str, torch.Tensor]) -> torch.Tensor:
        return torch.cat([self.encoder(stored["rgb"]), stored["state"]], dim=1)

    def spec(self) -> dict:
        return {
            "kind": self.kind,
            "out_dim": self.out_dim,
            "frame_stack": self.frame_stack,
            "image_size": self.image_size,
            "crop": self.crop,
            "feature_dim": self.feature_dim,
        }


# ---------------------------------------------------------------- builders from env spaces
def make_student_features(encoder_path: str | Path, obs_space: Any) -> StudentFeatures:
    """Load the frozen encoder and check it encodes the env's rgb stacks; raise CheckpointError otherwise."""
    shapes = space_shapes(obs_space)
    if "rgb" not in shapes or "state" not in shapes:
        raise CheckpointError(f"student needs 'rgb' and 'state' observations, env gives {shapes}")
    frame_stack, _, h, w = shapes["rgb"]
    if h != w:
        raise CheckpointError(f"rgb images must be square, env gives {shapes['rgb']}")
    enc = load_frozen_encoder(encoder_path, h, frame_stack)
    try:
        with torch.no_grad():
            z = enc(torch.zeros(1, 3 * frame_stack, h, w, dtype=torch.uint8))
    except Exception as e:
        raise CheckpointError(
            f"encoder checkpoint {encoder_path} does not fit the env's rgb stacks "
            f"{tuple(shapes['rgb'])} (as (1, {3 * frame_stack}, {h}, {w})): {e}"
        ) from e
    if z.dim() != 2 or z.shape[0] != 1:
        raise CheckpointError(f"encoder checkpoint {encoder_path}: expected output (1, d), got {tuple(z.shape)}")
    return StudentFeatures(enc, z.shape[1], str(encoder_path), h, frame_stack)


def make_oracle_features(obs_space: Any, feature_dim: int, far: float) -> OracleFeatures:
    """Fresh trainable depth encoder sized for the env's depth stacks."""

    shapes = space_shapes(obs_space)
    for key in ("depth", "state", "privileged"):
        if key not in shapes:
            raise CheckpointError(f"oracle needs a {key!r} observation, env gives {shapes}")
    frame_stack, h, _ = shapes["depth"]
    kwargs = {"frame_stack": frame_stack, "image_size": h, "feature_dim": int(feature_dim), "far": float(far)}
    return OracleFeatures(DepthEncoder(**kwargs), feature_dim, kwargs)


def make_pixel_features(obs_space: Any, crop: int, feature_dim: int) -> PixelFeatures:
    """Fresh trainable pixel encoder for the env's rgb stacks, fed their centre ``crop`` px."""
    shapes = space_shapes(obs_space)
    if "rgb" not in shapes or "state" not in shapes:
        raise CheckpointError(f"pixel policy needs 'rgb' and 'state' observations, env gives {shapes}")
    frame_stack, _, h, w = shapes["rgb"]
    if h != w or crop > h:
        raise CheckpointError(f"pixel policy: rgb {shapes['rgb']} must be square and at least {crop} px")
    return PixelFeatures(frame_stack, h, crop, feature_dim)


def _oracle_from_spec(spec: dict) -> OracleFeatures:

    kw = spec["encoder_kwargs"]
    return OracleFeatures(DepthEncoder(**kw), spec["depth_dim"], kw)


def _student_from_spec(spec: dict) -> StudentFeatures:
    if "encoder_artifact" in spec:  # embedded in the policy file: self-contained, no path to resolve
        try:
            enc = encoder_from_artifact(
                spec["encoder_artifact"], spec["encoder_path"] + " (embedded)", spec["image_size"], spec["frame_stack"]
            )
        except Exception as e:
            raise CheckpointError(f"embedded encoder of a policy file: {e}") from e
    else:  # policy files written before encoders were embedded
        enc = load_frozen_encoder(spec["encoder_path"], spec["image_size"], spec["frame_stack"])
    return StudentFeatures(enc, spec["enc_dim"], spec["encoder_path"], spec["image_size"], spec["frame_stack"])


register_feature_kind("identity", lambda s: IdentityFeatures(s["obs_dim"]))
register_feature_kind("oracle", _oracle_from_spec)
register_feature_kind("student", _student_from_spec)
register_feature_kind("pixel", lambda s: PixelFeatures(s["frame_stack"], s["image_size"], s["crop"], s["feature_dim"]))
