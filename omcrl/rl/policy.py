"""Saving, loading and running trained PPO policies with the common evaluation interface.

A policy file (``final.pt``) holds ``{"format", "spec", "model", "step", "meta"}``; ``spec`` is enough to
rebuild the network (feature kind and sizes, the env observation shapes it was trained on, hidden width). The
student's frozen encoder is *not* copied into the file: ``spec["features"]["encoder_path"]`` points to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from omcrl.rl.ppo import ActorCritic, FeatureExtractor, IdentityFeatures, OracleFeatures, StudentFeatures

FORMAT = "omcrl.rl.policy/1"


class CheckpointError(RuntimeError):
    """A checkpoint (policy, oracle or encoder) is missing, unreadable or does not fit the environment."""


def _depth_encoder_cls() -> type:
    try:
        from omcrl.models import DepthEncoder  # type: ignore[attr-defined]
    except ImportError:  # package __init__ may not re-export it
        from omcrl.models.encoder import DepthEncoder
    return DepthEncoder


def _load_encoder(path: str | Path, image_size: int, frame_stack: int) -> nn.Module:
    """Load the frozen pretrained encoder, turning every failure into a CheckpointError naming the file."""
    p = Path(path)
    if not p.exists():
        raise CheckpointError(f"encoder checkpoint {p} does not exist (run the pretraining stage first)")
    try:
        from omcrl.models import load_encoder  # type: ignore[attr-defined]
    except ImportError as e:
        raise CheckpointError(f"cannot load encoder {p}: omcrl.models.load_encoder is unavailable ({e})") from e
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


def space_shapes(space: Any) -> dict[str, list[int]]:
    """``{key: shape}`` of a (Dict) observation space; a Box gives ``{"obs": shape}``."""
    if hasattr(space, "spaces") and isinstance(space.spaces, dict):
        return {k: list(s.shape) for k, s in space.spaces.items()}
    return {"obs": list(space.shape)}


def make_student_features(encoder_path: str | Path, obs_space: Any) -> StudentFeatures:
    """Load the frozen encoder and check it encodes the env's rgb stacks; raise CheckpointError otherwise."""
    shapes = space_shapes(obs_space)
    if "rgb" not in shapes or "state" not in shapes:
        raise CheckpointError(f"student needs 'rgb' and 'state' observations, env gives {shapes}")
    frame_stack, _, h, w = shapes["rgb"]
    if h != w:
        raise CheckpointError(f"rgb images must be square, env gives {shapes['rgb']}")
    enc = _load_encoder(encoder_path, h, frame_stack)
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
    return OracleFeatures(_depth_encoder_cls()(**kwargs), feature_dim, kwargs)


def build_features(spec: dict) -> FeatureExtractor:
    """Rebuild a feature extractor from its ``spec()``."""
    kind = spec["kind"]
    if kind == "identity":
        return IdentityFeatures(spec["obs_dim"])
    if kind == "oracle":
        kw = spec["encoder_kwargs"]
        return OracleFeatures(_depth_encoder_cls()(**kw), spec["depth_dim"], kw)
    if kind == "student":
        enc = _load_encoder(spec["encoder_path"], spec["image_size"], spec["frame_stack"])
        return StudentFeatures(enc, spec["enc_dim"], spec["encoder_path"], spec["image_size"], spec["frame_stack"])
    raise CheckpointError(f"unknown feature kind {kind!r}")


class Policy:
    """A trained actor with the evaluation interface shared by learned policies and planners.

    ``act(obs, info)`` takes one *unbatched* env observation and returns the deterministic action
    ``clip(mean, -1, 1)`` (A,) float32; ``act_batch(obs, infos)`` does the same for a batched vector obs →
    (N, A). ``distribution(obs, infos, starts)`` makes a policy usable as a guide (mean, std) (N, A).
    """

    def __init__(self, agent: ActorCritic, name: str = "", checkpoint: str = "", meta: dict | None = None) -> None:
        self.agent = agent.eval()
        self.name, self.checkpoint, self.meta = name, checkpoint, dict(meta or {})

    @torch.no_grad()
    def act_batch(self, obs: Any, infos: Any = None) -> np.ndarray:
        mean, _, _ = self.agent(self.agent.features.preprocess(obs))
        return np.clip(mean.numpy(), -1.0, 1.0).astype(np.float32)

    def act(self, obs: Any, info: Any = None) -> np.ndarray:
        if isinstance(obs, dict):
            batched = {k: np.asarray(v)[None] for k, v in obs.items()}
        else:
            batched = np.asarray(obs)[None]
        return self.act_batch(batched)[0]

    @torch.no_grad()
    def distribution(self, obs: Any, infos: Any = None, starts: Any = None) -> tuple[np.ndarray, np.ndarray]:
        mean, std, _ = self.agent(self.agent.features.preprocess(obs))
        return mean.numpy().astype(np.float32), std.numpy().astype(np.float32)

    def reset(self) -> None:
        """Stateless; present so evaluation can treat policies and planners alike."""


def policy_payload(agent: ActorCritic, obs_shapes: dict, step: int, meta: dict | None = None) -> dict:
    return {
        "format": FORMAT,
        "spec": {**agent.spec(), "obs_shapes": obs_shapes},
        "model": agent.state_dict(),
        "step": int(step),
        "meta": dict(meta or {}),
    }


def read_payload(path: str | Path, what: str = "policy") -> dict:
    p = Path(path)
    if not p.exists():
        raise CheckpointError(f"{what} checkpoint {p} does not exist")
    try:
        # Policy files hold only tensors and plain containers: never unpickle arbitrary objects from them.
        payload = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as e:
        raise CheckpointError(f"{what} checkpoint {p} cannot be read: {e}") from e
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{what} checkpoint {p} is not an omcrl policy file (format {FORMAT!r})")
    return payload


def load_policy(path: str | Path, name: str = "", expect_kind: str | None = None, obs_space: Any = None) -> Policy:
    """Load a policy file; optionally check its feature kind and the observation shapes of ``obs_space``."""
    payload = read_payload(path, expect_kind or "policy")
    spec = payload["spec"]
    kind = spec["features"]["kind"]
    if expect_kind is not None and kind != expect_kind:
        raise CheckpointError(f"checkpoint {path} holds a {kind!r} policy, expected {expect_kind!r}")
    if obs_space is not None:
        env_shapes, ck_shapes = space_shapes(obs_space), spec.get("obs_shapes", {})
        bad = {k: (ck_shapes[k], env_shapes.get(k)) for k in ck_shapes if env_shapes.get(k) != ck_shapes[k]}
        if bad:
            raise CheckpointError(
                f"checkpoint {path} was trained on observation shapes that differ from the env: "
                + ", ".join(f"{k}: checkpoint {a} vs env {b}" for k, (a, b) in bad.items())
            )
    agent = ActorCritic(
        build_features(spec["features"]),
        spec["act_dim"],
        spec["hidden"],
        layer_norm=spec.get("layer_norm", True),
    )
    try:
        agent.load_state_dict(payload["model"])
    except RuntimeError as e:
        raise CheckpointError(f"checkpoint {path}: weights do not match its own spec: {e}") from e
    return Policy(
        agent,
        name=name or payload.get("meta", {}).get("name") or Path(path).parent.name,
        checkpoint=str(path),
        meta=payload.get("meta"),
    )
