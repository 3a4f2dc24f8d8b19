"""Saving, loading and running trained PPO policies with the common evaluation interface.

A policy file (``final.pt``) holds ``{"format", "spec", "model", "step", "meta"}`` and, for a policy on a frozen
pretrained encoder, ``"encoder"`` (the encoder artifact itself), so the file is self-contained; ``spec`` is enough
to rebuild the network (feature kind and sizes, the env observation shapes it was trained on, hidden width).
``spec["features"]["encoder_path"]`` records where the encoder came from. An end-to-end pixel encoder's weights
are part of ``model``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from omcrl.models.actor_critic import ActorCritic
from omcrl.models.artifact import encoder_artifact
from omcrl.models.features import (
    CheckpointError,
    build_features,
    make_oracle_features,
    make_pixel_features,
    make_student_features,
    space_shapes,
)
from omcrl.runs import rerun_command, verify_artifact
from omcrl.utils.io import load_torch

__all__ = [
    "FORMAT",
    "CheckpointError",
    "Policy",
    "build_features",
    "load_policy",
    "make_oracle_features",
    "make_pixel_features",
    "make_student_features",
    "policy_payload",
    "read_payload",
    "space_shapes",
]

FORMAT = "omcrl.rl.policy/1"


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
        mean, _ = self.agent.distribution(self.agent.prepare(obs))
        return np.clip(mean.numpy(), -1.0, 1.0).astype(np.float32)

    def act(self, obs: Any, info: Any = None) -> np.ndarray:
        if isinstance(obs, dict):
            batched = {k: np.asarray(v)[None] for k, v in obs.items()}
        else:
            batched = np.asarray(obs)[None]
        return self.act_batch(batched)[0]

    @torch.no_grad()
    def distribution(self, obs: Any, infos: Any = None, starts: Any = None) -> tuple[np.ndarray, np.ndarray]:
        mean, std = self.agent.distribution(self.agent.prepare(obs))
        return mean.numpy().astype(np.float32), std.numpy().astype(np.float32)

    def reset(self) -> None:
        """Stateless; present so evaluation can treat policies and planners alike."""


def policy_payload(agent: ActorCritic, obs_shapes: dict, step: int, meta: dict | None = None) -> dict:
    """The policy file's content. A frozen pretrained encoder is embedded (``"encoder"``), so the file is
    self-contained: it loads from any folder, and after the encoder's own file is moved or deleted."""
    payload = {
        "format": FORMAT,
        "spec": {**agent.spec(), "obs_shapes": obs_shapes},
        "model": agent.state_dict(),
        "step": int(step),
        "meta": dict(meta or {}),
    }
    if agent.features.kind == "student":
        payload["encoder"] = encoder_artifact(agent.features.encoder)
    return payload


def read_payload(path: str | Path, what: str = "policy") -> dict:
    p = Path(path)
    if not p.exists():
        raise CheckpointError(f"{what} checkpoint {p} does not exist")
    # A run's final.pt must still be what its run recorded: a damaged teacher or policy is never used.
    verify_artifact(p, f"{what} checkpoint", rerun_command(p.parent, "train") + " (after deleting its final.pt)")
    # Policy files hold only tensors and plain containers: never unpickle arbitrary objects from them.
    payload = load_torch(p, f"{what} checkpoint", CheckpointError)
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
    feats = spec["features"]
    if "encoder" in payload:
        feats = {**feats, "encoder_artifact": payload["encoder"]}
    agent = ActorCritic(
        build_features(feats),
        spec["act_dim"],
        spec["hidden"],
        layer_norm=spec.get("layer_norm", True),
    )
    try:
        agent.load_state_dict(payload["model"])
    except RuntimeError as e:
        raise CheckpointError(f"checkpoint {path}: weights do not match its own spec: {e}") from e
    # A policy acts in the precision it was trained in (rollouts, evaluation and as a guide alike).
    precision = spec.get("precision", "fp32")
    if precision not in ("fp32", "bf16"):
        raise CheckpointError(f"checkpoint {path}: spec.precision is {precision!r}, expected 'fp32' or 'bf16'")
    agent.precision = precision
    return Policy(
        agent,
        name=name or payload.get("meta", {}).get("name") or Path(path).parent.name,
        checkpoint=str(path),
        meta=payload.get("meta"),
    )
