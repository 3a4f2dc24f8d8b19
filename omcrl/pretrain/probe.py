"""Linear probe of a frozen encoder: how well do its features encode obstacle geometry?

Ridge regression from features z = φ(f(h_t)) to goal-independent privileged quantities at step t:

* ``distance``, ``bearing_sin``, ``bearing_cos`` — the nearest obstacle surface ‖Δp_obs‖ (m) and its bearing
  atan2(dy, dx) in the body frame. The nearest obstacle is often beside or behind the drone, outside the
  camera's 82.6° field of view, so these are partly unobservable from the images by construction.
* ``depth_ahead`` — median depth (m) of the central patch of the newest depth frame: free space ahead.
* ``depth_balance`` — mean depth (m) of the left third minus the right third of the middle rows: which side
  is more open. Both come from the privileged depth camera and are visible in the RGB frames.

Train and held-out samples come from disjoint episodes, so a probe cannot memorise an episode, and the ridge
penalty is chosen by cross-validation grouped by episode on the training episodes only.
"""

from __future__ import annotations

import numpy as np
import torch

from omcrl.data.dataset import DatasetError, TrajectoryDataset

TARGETS = ("distance", "bearing_sin", "bearing_cos", "depth_ahead", "depth_balance")
ALPHAS = tuple(float(a) for a in np.logspace(-1, 5, 13))


def probe_targets(privileged: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Probe targets, (N, 5), from privileged (N, 6) and the newest depth frames (N, H, W) in metres."""
    d = privileged[:, :3].astype(np.float64)
    ang = np.arctan2(d[:, 1], d[:, 0])
    h, w = depth.shape[1:]
    centre = depth[:, 3 * h // 8 : 5 * h // 8, 3 * w // 8 : 5 * w // 8].reshape(len(depth), -1)
    rows = depth[:, h // 4 : 3 * h // 4].astype(np.float64)
    balance = rows[:, :, : w // 3].mean((1, 2)) - rows[:, :, -(w // 3) :].mean((1, 2))
    return np.stack([np.linalg.norm(d, axis=1), np.sin(ang), np.cos(ang), np.median(centre, 1), balance], 1)


def _collect(
    encoder: torch.nn.Module,
    ds: TrajectoryDataset,
    episodes: np.ndarray,
    n: int,
    rng: np.random.Generator,
    batch_size: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features (n, d), targets (n, 5) and episode ids (n,) at steps drawn uniformly from ``episodes``."""
    w = ds.episode_lengths[episodes].astype(np.float64)
    eps = rng.choice(episodes, size=n, p=w / w.sum())
    feats, targets, groups = [], [], []
    for ep in np.unique(eps):
        ts = np.sort(rng.integers(0, ds.episode_lengths[ep], size=int((eps == ep).sum())))
        priv = ds.read(int(ep), "privileged")[ts]
        depth = np.asarray(ds.read(int(ep), "depth")[ts], np.float32)
        groups.append(np.full(len(ts), ep))
        stacks = ds.read_stacks(int(ep), ts, encoder.frame_stack)
        with torch.no_grad():
            for i in range(0, len(ts), batch_size):
                feats.append(encoder(torch.from_numpy(stacks[i : i + batch_size])).numpy())
        targets.append(probe_targets(priv, depth))
    return np.concatenate(feats).astype(np.float64), np.concatenate(targets), np.concatenate(groups)


def split_episodes(
    episodes: np.ndarray, test_fraction: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(held-out, training) episode ids: a random ``test_fraction`` of ``episodes`` (at least one each side)."""
    perm = rng.permutation(episodes)
    k = min(max(1, round(test_fraction * len(episodes))), len(episodes) - 1)
    return perm[:k], perm[k:]


def fit_probes(x: np.ndarray, y: np.ndarray, groups: np.ndarray, alpha: float | None = None) -> list:
    """One standardised ridge model per target column of ``y`` (N, len(TARGETS)) on features ``x`` (N, d).

    ``alpha`` None chooses the penalty per target from :data:`ALPHAS` by cross-validation grouped by ``groups``
    (episode ids), when there are at least 3 groups; else ``alpha`` (default 1.0) is used as is.
    """
    # scikit-learn loads here, not with the module: importing it costs ~1 s, which every CLI start and every
    # import of omcrl.rl (whose method specs name pretraining runs) would otherwise pay.
    from sklearn.linear_model import Ridge
    from sklearn.model_selection import GridSearchCV, GroupKFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    models = []
    for i in range(y.shape[1]):
        model = make_pipeline(StandardScaler(), Ridge(alpha=alpha if alpha is not None else 1.0))
        if alpha is None and len(np.unique(groups)) >= 3:
            # Consecutive frames are near-duplicates: folds must split by episode, or the CV picks a penalty
            # that memorises trajectories and the held-out R² collapses.
            cv = GroupKFold(n_splits=min(5, len(np.unique(groups))))
            search = GridSearchCV(model, {"ridge__alpha": ALPHAS}, cv=cv, scoring="r2")
            model = search.fit(x, y[:, i], groups=groups).best_estimator_
        else:
            model.fit(x, y[:, i])
        models.append(model)
    return models


def probe(
    encoder: torch.nn.Module,
    dataset: TrajectoryDataset,
    n_samples: int = 2000,
    test_fraction: float = 0.3,
    alpha: float | None = None,
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
    alpha : ridge regularisation (features are standardised first); None chooses it per target from
        ``ALPHAS`` by 5-fold cross-validation grouped by episode on the training episodes.

    Returns
    -------
    ``{target: held-out R² for each of TARGETS, "n_train": int, "n_test": int}``.
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
    test_eps, train_eps = split_episodes(np.arange(len(dataset)), test_fraction, rng)
    n_test = max(1, round(test_fraction * n_samples))
    encoder.eval()
    x_tr, y_tr, g_tr = _collect(encoder, dataset, train_eps, n_samples - n_test, rng, batch_size)
    x_te, y_te, _ = _collect(encoder, dataset, test_eps, n_test, rng, batch_size)
    models = fit_probes(x_tr, y_tr, g_tr, alpha)
    from sklearn.metrics import r2_score

    out = {t: float(r2_score(y_te[:, i], m.predict(x_te))) for i, (t, m) in enumerate(zip(TARGETS, models))}
    return {**out, "n_train": len(x_tr), "n_test": len(x_te)}
