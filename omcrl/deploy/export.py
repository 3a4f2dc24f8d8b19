"""ONNX export of a visuomotor policy: (RGB stack, state) → action, preprocessing inside the graph (paper VI-B).

The exported graph maps

* ``rgb``   uint8   (1, 3L, H, W): the last L camera frames, oldest first, each RGB, at the env's image size H;
* ``state`` float32 (1, 12): v (3, body, m/s), ω (3, rad/s), θ (roll, pitch, yaw, rad), Δp_goal (3, body, m);

to ``action`` float32 (1, 3) in [−1, 1] = (vx, vy, ωz) as fractions of ``action_scale`` (the policy's Gaussian
mean, clipped). Centre crop, the /255 scaling and the encoder (frozen or end-to-end) are in the graph, so a
runtime needs nothing of the kit. The observation spec is stored in the model's metadata under
``omcrl_spec`` (JSON): image size, frame stack, crop, state layout, action layout and scaling, control rate,
camera FOV, method and source checkpoint. The oracle cannot be exported: it needs privileged inputs.
"""

from __future__ import annotations

import contextlib
import json
import logging
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import nn

from omcrl.config import ConfigError
from omcrl.rl.policy import load_policy
from omcrl.runs import verify_artifact
from omcrl.utils.io import atomic_write_bytes

SPEC_KEY = "omcrl_spec"
STATE_LAYOUT = ("vx", "vy", "vz", "wx", "wy", "wz", "roll", "pitch", "yaw", "goal_x", "goal_y", "goal_z")
ACTION_LAYOUT = ("vx", "vy", "wz")


class ExportError(RuntimeError):
    """The policy cannot be exported (unknown kind, privileged inputs, missing config)."""


class _Deployable(nn.Module):
    """(rgb uint8 (B, 3L, H, W), state (B, 12)) → clip(actor mean, −1, 1) (B, 3)."""

    def __init__(self, agent: nn.Module) -> None:
        super().__init__()
        feats = agent.features
        self.kind = feats.kind
        # The frozen encoder is deliberately not a submodule of StudentFeatures; here it must be one.
        self.encoder = feats.encoder
        self.crop = int(getattr(feats, "crop", 0))
        self.actor = agent.actor

    def forward(self, rgb: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        if self.kind == "pixel":
            side = rgb.shape[-1]
            o = (side - self.crop) // 2
            rgb = rgb[..., o : o + self.crop, o : o + self.crop]
        z = self.encoder(rgb).float()
        return torch.clamp(self.actor(torch.cat([z, state], dim=1)), -1.0, 1.0)


def _env_section(policy_path: Path) -> dict:
    """The env section of the run's ``config.yaml`` beside the policy file."""
    import yaml

    cfg_path = policy_path.parent / "config.yaml"
    if not cfg_path.is_file():
        raise ExportError(f"{cfg_path} not found: the policy's run folder must hold its config.yaml")
    verify_artifact(cfg_path, "run config", "it is written by the run's training; restore it or train the run again")
    try:
        doc = yaml.safe_load(cfg_path.read_text(encoding="utf-8")) or {}
    except (OSError, ValueError, yaml.YAMLError) as e:
        first = " ".join(str(e).split())[:120]
        raise ExportError(
            f"{cfg_path} is not a readable config ({first}); it is written by the run's training"
        ) from None
    env = doc.get("env") if isinstance(doc, dict) else None
    if not isinstance(env, dict):
        raise ExportError(f"{cfg_path}: no 'env' section")
    return env


def resolve_policy(policy: str | Path) -> Path:
    """A run folder or a ``final.pt`` → the policy file; FileNotFoundError naming what is missing."""
    p = Path(policy)
    if p.is_dir():
        p = p / "final.pt"
    if not p.is_file():
        raise FileNotFoundError(f"policy {p} does not exist (give a run folder or its final.pt)")
    return p


@contextlib.contextmanager
def _quiet_exporter() -> Iterator[None]:
    """The exporter without its console noise: a warning per torchvision operator it cannot register (the kit
    uses none) and a FutureWarning from its tree utilities; real export errors still raise."""
    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registration.level
    registration.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning, message=r".*LeafSpec.*")
            yield
    finally:
        registration.setLevel(level)


def export_onnx(policy: str | Path, out: str | Path | None = None, opset: int = 18) -> Path:
    """Export a trained visuomotor policy to one ONNX file; returns its path.

    Parameters
    ----------
    policy : a run folder (``.../seed<k>``) or its ``final.pt``.
    out : the ONNX file (default: ``policy.onnx`` beside ``final.pt``); written atomically.
    opset : ONNX opset.

    Raises ExportError for the oracle (privileged depth and obstacle inputs) and for unknown policy kinds.
    """
    import onnx

    path = resolve_policy(policy)
    pol = load_policy(path)
    kind = pol.agent.features.kind
    if kind == "oracle":
        raise ExportError(
            f"{path} is the oracle: it needs privileged inputs (depth and the nearest-obstacle vector) that the "
            "drone does not have; export a visuomotor policy (ours, curl, ppo, npe ...)"
        )
    if kind not in ("student", "pixel"):
        raise ExportError(f"{path}: policy kind {kind!r} has no pixel encoder to export")
    env = _env_section(path)
    shapes = pol.agent.spec()["features"]
    frame_stack, image_size = int(env["frame_stack"]), int(env["image_size"])
    model = _Deployable(pol.agent).eval()
    rgb = torch.zeros(1, 3 * frame_stack, image_size, image_size, dtype=torch.uint8)
    state = torch.zeros(1, 12)
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad(), _quiet_exporter():
        # The torch.export-based exporter (the default since torch 2.9; the TorchScript one is deprecated).
        torch.onnx.export(
            model,
            (rgb, state),
            f"{tmp}/model.onnx",
            input_names=["rgb", "state"],
            output_names=["action"],
            opset_version=opset,
            dynamo=True,
            external_data=False,
            verbose=False,
        )
        m = onnx.load(f"{tmp}/model.onnx")
    spec = {
        "format": 1,
        "method": str(pol.meta.get("method", pol.name)),
        "source": str(path),
        "kind": kind,
        "image_size": image_size,
        "frame_stack": frame_stack,
        "crop": int(shapes.get("crop", shapes.get("image_size", image_size))),
        "rgb": [1, 3 * frame_stack, image_size, image_size],
        "state_layout": list(STATE_LAYOUT),
        "action_layout": list(ACTION_LAYOUT),
        "action_scale": {"max_speed": float(env["max_speed"]), "max_yaw_rate": float(env["max_yaw_rate"])},
        "control_hz": float(env["control_hz"]),
        "fov_deg": float(env["fov_deg"]),
        "altitude": float(env["altitude"]),
    }
    entry = m.metadata_props.add()
    entry.key, entry.value = SPEC_KEY, json.dumps(spec)
    onnx.checker.check_model(m)
    out_path = Path(out) if out is not None else path.with_name("policy.onnx")
    atomic_write_bytes(out_path, m.SerializeToString())
    return out_path


def export_stage(cfg: Any, policy: str | None = None, out: str | None = None) -> Path:
    """CLI stage ``export``: ``python -m omcrl export --policy <run or final.pt> [--out FILE]``."""

    if policy is None:
        raise ConfigError("stage 'export' needs --policy <run folder or final.pt>")
    return export_onnx(policy, out)
