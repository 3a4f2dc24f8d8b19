"""onnxruntime policy with the kit's ``act(obs, info)`` interface, so ``omcrl.eval.evaluate`` can fly it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from omcrl.deploy.export import SPEC_KEY


class ModelSpecError(ValueError):
    """An ONNX model's observation spec does not match the camera or state it would be fed."""


class OnnxPolicy:
    """An exported policy run by onnxruntime on the CPU.

    Parameters
    ----------
    path : the ONNX file written by :func:`omcrl.deploy.export_onnx`.
    threads : intra-op threads (1: the latency of one core, what an on-board computer has).

    Attributes
    ----------
    spec : the observation spec from the model's metadata (image_size, frame_stack, action_scale, ...).
    """

    def __init__(self, path: str | Path, threads: int = 1) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"ONNX model {self.path} does not exist (export one with: python -m omcrl export)")
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(self.path), so, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise ModelSpecError(f"ONNX model {self.path} cannot be loaded: {e}") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        if SPEC_KEY not in meta:
            raise ModelSpecError(f"ONNX model {self.path} has no '{SPEC_KEY}' metadata: not exported by omcrl")
        self.spec: dict = json.loads(meta[SPEC_KEY])
        self.name = f"onnx:{self.spec.get('method', self.path.stem)}"
        self.checkpoint = str(self.path)

    def check(self, image_size: int, frame_stack: int, state_dim: int = 12) -> None:
        """Raise ModelSpecError unless the model takes ``frame_stack`` frames of ``image_size`` px and the state."""
        want = {"image_size": image_size, "frame_stack": frame_stack, "state": state_dim}
        got = {
            "image_size": self.spec["image_size"],
            "frame_stack": self.spec["frame_stack"],
            "state": len(self.spec["state_layout"]),
        }
        bad = {k: (want[k], got[k]) for k in want if int(want[k]) != int(got[k])}
        if bad:
            raise ModelSpecError(
                f"ONNX model {self.path} does not fit the configured camera/state: "
                + ", ".join(f"{k} configured {a}, model {b}" for k, (a, b) in bad.items())
            )

    def run(self, rgb: np.ndarray, state: np.ndarray) -> np.ndarray:
        """rgb uint8 (B, 3L, H, W), state float32 (B, 12) → action float32 (B, 3) in [−1, 1]."""
        out = self.session.run(["action"], {"rgb": rgb, "state": state.astype(np.float32, copy=False)})
        return out[0]

    def act(self, obs: dict, info: Any = None) -> np.ndarray:
        """One env observation (``rgb`` (L, 3, H, W) uint8, ``state`` (12,)) → action (3,) float32."""
        rgb = np.asarray(obs["rgb"], np.uint8)
        rgb = np.ascontiguousarray(rgb.reshape(1, -1, rgb.shape[-2], rgb.shape[-1]))
        return self.run(rgb, np.asarray(obs["state"], np.float32)[None])[0]

    def reset(self) -> None:
        """Stateless (present so evaluation treats it like any policy)."""
