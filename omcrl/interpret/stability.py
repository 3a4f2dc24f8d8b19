"""Feature stability under input disturbances (paper VI-B, Fig. 14): numbers where the paper shows t-SNE.

Frames from successful trajectories are disturbed (:data:`PERTURBATIONS`: brightness, hue, random masking, as in
the paper) and passed through an encoder with their clean originals. Two numbers per encoder and disturbance:

- ``rel_distance``: the mean cosine distance between a frame's clean and disturbed features, divided by the mean
  cosine distance between the clean features of two different frames. 0: the disturbance moves nothing; 1: it
  moves a frame as far as an unrelated frame is.
- ``knn_acc``: the share of disturbed frames whose nearest clean feature (cosine) is their own clean frame.

:func:`tsne_embedding` projects clean and disturbed features together for the figure.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
import pandas as pd

from omcrl.config import ConfigError
from omcrl.interpret.shift import encode

PERTURBATIONS = ("brightness", "hue", "mask")


def perturb(stacks: np.ndarray, kind: str, seed: int = 0, strength: float = 1.0) -> np.ndarray:
    """Disturbed copies of observation stacks (N, 3L, H, W) uint8, one random draw per stack (all its frames).

    ``brightness``: × U(1 − 0.5s, 1 + 0.5s); ``hue``: rotation by U(−40s, 40s) degrees; ``mask``: each cell of an
    8 × 8 grid set to black with probability 0.3s. ``s = strength``; draws are reproducible from ``seed``.
    """
    if kind not in PERTURBATIONS:
        raise ConfigError(f"perturbation: got {kind!r}, known perturbations are {list(PERTURBATIONS)}")
    x = np.asarray(stacks, np.uint8)
    n, ch, h, w = x.shape
    rng = np.random.default_rng([seed, PERTURBATIONS.index(kind)])
    frames = x.reshape(n, ch // 3, 3, h, w)
    out = frames.copy()
    if kind == "brightness":
        f = rng.uniform(1 - 0.5 * strength, 1 + 0.5 * strength, n)[:, None, None, None, None]
        out = np.clip(frames.astype(np.float32) * f, 0, 255).astype(np.uint8)
    elif kind == "hue":
        shift = rng.uniform(-40 * strength, 40 * strength, n)
        for i in range(n):
            for j in range(frames.shape[1]):
                hsv = cv2.cvtColor(np.ascontiguousarray(frames[i, j].transpose(1, 2, 0)), cv2.COLOR_RGB2HSV)
                # OpenCV keeps hue in [0, 180) for uint8 images: degrees / 2.
                hsv[..., 0] = ((hsv[..., 0].astype(np.int32) + round(shift[i] / 2)) % 180).astype(np.uint8)
                out[i, j] = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB).transpose(2, 0, 1)
    else:
        cells = rng.random((n, 8, 8)) < 0.3 * strength
        keep = ~np.kron(cells, np.ones((-(-h // 8), -(-w // 8)), bool))[:, :h, :w]
        out = frames * keep[:, None, None].astype(np.uint8)
    return out.reshape(n, ch, h, w)


def _unit(z: np.ndarray) -> np.ndarray:
    z = np.asarray(z, np.float64)
    return z / np.maximum(np.linalg.norm(z, axis=1, keepdims=True), 1e-12)


def stability(clean: np.ndarray, disturbed: np.ndarray, seed: int = 0) -> dict[str, float]:
    """Stability of features under a disturbance: row i of ``disturbed`` (N, d) is row i of ``clean`` disturbed.

    Returns
    -------
    ``{"rel_distance", "knn_acc", "clean_disturbed", "unrelated", "frames"}``: the cosine distances
    (mean over frames) between clean and disturbed copies, and between clean features of random different frames
    (drawn with ``seed``); their ratio; the nearest-neighbour retrieval accuracy.
    """
    a, b = _unit(clean), _unit(disturbed)
    if a.shape != b.shape or len(a) < 2:
        raise ValueError(f"stability: need two feature sets of the same shape (N >= 2, d), got {a.shape}, {b.shape}")
    n = len(a)
    same = 1.0 - (a * b).sum(1)
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, 4 * n)
    j = (i + rng.integers(1, n, 4 * n)) % n  # j != i
    unrelated = 1.0 - (a[i] * a[j]).sum(1)
    nearest = (b @ a.T).argmax(1)
    return {
        "rel_distance": float(same.mean() / max(unrelated.mean(), 1e-12)),
        "knn_acc": float((nearest == np.arange(n)).mean()),
        "clean_disturbed": float(same.mean()),
        "unrelated": float(unrelated.mean()),
        "frames": n,
    }


def stability_table(
    encoders: Mapping[str, Any], stacks: np.ndarray, kinds: tuple[str, ...] = PERTURBATIONS, seed: int = 0
) -> tuple[pd.DataFrame, dict[str, dict[str, np.ndarray]]]:
    """:func:`stability` of every encoder under every perturbation of ``stacks`` (N, 3L, H, W) uint8.

    Returns the table (one row per encoder and perturbation) and the features ``{encoder: {"clean": z,
    kind: z, ...}}`` (N, d) for :func:`tsne_embedding`.
    """

    disturbed = {k: perturb(stacks, k, seed) for k in kinds}
    rows, feats = [], {}
    for name, enc in encoders.items():
        z = {"clean": encode(enc, stacks)[0]}
        for k, x in disturbed.items():
            z[k] = encode(enc, x)[0]
            rows.append({"encoder": name, "perturbation": k, **stability(z["clean"], z[k], seed)})
        feats[name] = z
    return pd.DataFrame(rows), feats


def tsne_embedding(features: Mapping[str, np.ndarray], seed: int = 0, perplexity: float = 30.0) -> pd.DataFrame:
    """2-D t-SNE (scikit-learn) of feature sets ``{condition: (N, d)}`` embedded together (cosine metric).

    Returns one row per feature: ``x``, ``y``, ``condition``, ``frame`` (the row index within its set).
    """
    from sklearn.manifold import TSNE

    names = list(features)
    z = np.concatenate([np.asarray(features[k], np.float64) for k in names])
    perp = float(min(perplexity, max(2.0, (len(z) - 1) / 3)))
    xy = TSNE(2, perplexity=perp, metric="cosine", init="pca", random_state=seed).fit_transform(z)
    cond = np.concatenate([[k] * len(features[k]) for k in names])
    frame = np.concatenate([np.arange(len(features[k])) for k in names])
    return pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "condition": cond, "frame": frame})
