"""Linear probe of a frozen encoder: how well do its features encode obstacle geometry?

Ridge regression from features z = φ(f(h_t)) to goal-independent privileged quantities at step t:
the distance to the nearest obstacle surface ‖Δp_obs‖ (m) and its bearing as sin / cos of atan2(dy, dx)
(body frame). Train and held-out samples come from disjoint episodes, so a probe cannot memorise an episode.
"""

from __future__ import annotations

import numpy as np
import torch
from sklearn.linear_model import Ridge
from sklearn.metrics import r2_score
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from omcrl.data.dataset import DatasetError, TrajectoryDataset

TARGETS = ("distance", "bearing_sin", "bearing_cos")


def probe_targets(privileged: np.ndarray) -> np.ndarray:
    """(N, 6) privileged → (N, 3): obstacle distance (m), sin and cos of its bearing."""
    d = privileged[:, :3].astype(np.float64)
    ang = np.arctan2(d[:, 1], d[:, 0])
    return np.stack([np.linalg.norm(d, axis=1), np.sin(ang), np.cos(ang)], axis=1)


def _collect(
    encoder: torch.nn.Module,
    ds: TrajectoryDataset,
    episodes: np.ndarray,
    n: int,
    rng: np.random.Generator,
    batch_size: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Features (n, d) and targets (n, 3) at steps drawn uniformly from ``episodes``."""
    w = ds.episode_lengths[episodes].astype(np.float64)
    eps = rng.choice(episodes, size=n, p=w / w.sum())
    feats, targets = [], []
    for ep in np.unique(eps):
        ts = np.sort(rng.integers(0, ds.episode_lengths[ep], size=int((eps == ep).sum())))
        priv = ds.read(int(ep), "privileged")[ts]
        stacks = ds.read_stacks(int(ep), ts, encoder.frame_stack)
        with torch.no_grad():
            for i in range(0, len(ts), batch_size):
                feats.append(encoder(torch.from_numpy(stacks[i : i + batch_size])).numpy())
        targets.append(probe_targets(priv))
    return np.concatenate(feats).astype(np.float64), np.concatenate(targets)


def probe(
    encoder: torch.nn.Module,
    dataset: TrajectoryDataset,
    n_samples: int = 2000,
    test_fraction: float = 0.3,
    alpha: float = 1.0,
    seed: int = 0,
    batch_size: int = 128,
) -> dict:
    """Fit ridge probes on frozen features and report held-out R² per target.

    Parameters
    ----------
    encoder : a :class:`omcrl.models.FrozenEncoder` (pretrained or :func:`omcrl.models.random_encoder`).
    dataset : trajectory dataset with at least 2 episodes; its image size must be the encoder's
        ``crop_from`` (center-cropped inside the encoder) or ``crop_to``.
    n_samples : total (train + held-out) steps sampled.
    test_fraction : share of *episodes* held out.
    alpha : ridge regularisation (features are standardised first).

    Returns
    -------
    ``{"distance": R², "bearing_sin": R², "bearing_cos": R², "n_train": int, "n_test": int}``.
    """
    if len(dataset) < 2:
        raise DatasetError(
            f"dataset {dataset.path}: probe needs >= 2 episodes for an episode split, got {len(dataset)}"
        )
    if dataset.image_size not in (encoder.crop_from, encoder.crop_to):
        raise DatasetError(
            f"dataset {dataset.path}: field 'image_size' expected {encoder.crop_from} "
            f"(encoder crop_from), got {dataset.image_size}"
        )
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(dataset))
    n_test_eps = min(max(1, round(test_fraction * len(dataset))), len(dataset) - 1)
    test_eps, train_eps = perm[:n_test_eps], perm[n_test_eps:]
    n_test = max(1, round(test_fraction * n_samples))
    encoder.eval()
    x_tr, y_tr = _collect(encoder, dataset, train_eps, n_samples - n_test, rng, batch_size)
    x_te, y_te = _collect(encoder, dataset, test_eps, n_test, rng, batch_size)
    model = make_pipeline(StandardScaler(), Ridge(alpha=alpha)).fit(x_tr, y_tr)
    pred = model.predict(x_te)
    out = {t: float(r2_score(y_te[:, i], pred[:, i])) for i, t in enumerate(TARGETS)}
    return {**out, "n_train": len(x_tr), "n_test": len(x_te)}
