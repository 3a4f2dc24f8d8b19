"""Feature shift between scenes: how far an encoder's features move when the scene (or only its look) changes.

The zero-shot question of the paper is whether features learnt in box stay meaningful in furniture, barrier and
tree. This module measures the distance between the feature distributions of frames from pilot trajectories in
two settings (two scenes, or one layout with two looks; see ``Disturbance.appearance``):

- :func:`mmd_rbf`: squared maximum mean discrepancy with a Gaussian kernel (biased estimate, median-heuristic
  bandwidth on the pooled features); 0 for identical samples;
- :func:`frechet_distance`: the Fréchet distance between Gaussians fitted to the two feature sets (as FID does);
- :func:`saturated_share`: the share of f's tanh outputs with |h| > 0.99 (saturated units carry no gradient and
  little information; a scene that saturates more of them is off the encoder's training distribution).

:func:`pilot_frames` collects observation stacks along scripted-pilot trajectories (Hybrid APF on the true map),
so the frames of every setting come from comparable flight; :func:`shift_table` runs the comparison for several
encoders and scenes and :func:`omcrl.viz.shift.plot_feature_shift` draws it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
import torch

from omcrl.envs import make_env
from omcrl.planners import HybridAPF
from omcrl.pretrain.probe import TARGETS, fit_probes, probe_targets, split_episodes

SATURATION = 0.99


def pilot_frames(scene: str, episodes: int, seed: int = 0, **kwargs: Any) -> np.ndarray:
    """RGB stacks seen along scripted-pilot episodes: ``pilot_samples(...)["rgb"]`` (N, 3L, H, W) uint8; the keyword
    arguments are :func:`pilot_samples`'s."""
    return pilot_samples(scene, episodes, seed, **kwargs)["rgb"]


def pilot_samples(
    scene: str,
    episodes: int,
    seed: int = 0,
    *,
    env_config: Any = None,
    disturbance: Any = None,
    every: int = 2,
    max_steps: int = 150,
    masks: bool = False,
    successful_only: bool = False,
    privileged: bool = False,
) -> dict[str, np.ndarray]:
    """Observations along scripted-pilot episodes (Hybrid APF on the true map).

    Parameters
    ----------
    scene : the layout generator (``box``, ``furniture``, ``barrier``, ``tree``).
    episodes : episodes to fly; episode ``i`` resets with seed ``seed + i`` (same seeds give the same layouts,
        starts and goals, so two calls differing only in ``disturbance`` see the same geometry).
    env_config : an :class:`omcrl.config.EnvConfig` (image size, frame stack, arena); default the env's defaults.
    disturbance : passed to the env, e.g. ``{"appearance": "box"}``.
    every : keep every ``every``-th step (consecutive 10 Hz frames are near duplicates).
    max_steps : at most this many steps per episode.
    masks : also return the obstacle pixels of the newest frame (:meth:`NavEnv.obstacle_mask`; one extra render
        per kept step).
    successful_only : keep only the steps of episodes that reached the goal.
    privileged : also return the privileged vector and the newest depth frame (what the linear probe's targets
        are computed from, :func:`omcrl.pretrain.probe.probe_targets`).

    Returns
    -------
    ``{"rgb": (N, 3L, H, W) uint8 stacks the encoder takes, "state": (N, 12) float32, "episode": (N,) int,
    "mask": (N, H, W) bool (with ``masks``), "privileged": (N, 6) float32 and "depth": (N, H, W) float32 in m
    (with ``privileged``)}``.
    """

    env = make_env(scene, seed=seed, config=env_config, disturbance=disturbance)
    pilot = HybridAPF(env.cfg).bind(env)
    keep: dict[str, list] = {"rgb": [], "state": [], "episode": [], "mask": [], "privileged": [], "depth": []}
    try:
        for i in range(episodes):
            obs, info = env.reset(seed=seed + i)
            pilot.reset(info)
            ep: dict[str, list] = {k: [] for k in keep}
            for t in range(max_steps):
                if t % every == 0:
                    rgb = obs["rgb"]  # (L, 3, H, W)
                    ep["rgb"].append(rgb.reshape(-1, *rgb.shape[-2:]))
                    ep["state"].append(np.asarray(obs["state"], np.float32))
                    ep["episode"].append(i)
                    if masks:
                        ep["mask"].append(env.obstacle_mask())
                    if privileged:
                        ep["privileged"].append(np.asarray(obs["privileged"], np.float32))
                        ep["depth"].append(np.asarray(obs["depth"][-1], np.float32))
                obs, _, term, trunc, info = env.step(pilot.act(obs, info))
                if term or trunc:
                    break
            if not successful_only or info.get("metrics", {}).get("success", False):
                for k in keep:
                    keep[k] += ep[k]
    finally:
        env.close()
    if not keep["rgb"]:
        raise RuntimeError(f"pilot_samples: no frames kept from {episodes} episodes in {scene!r}")
    out = {
        "rgb": np.stack(keep["rgb"]).astype(np.uint8),
        "state": np.stack(keep["state"]),
        "episode": np.asarray(keep["episode"]),
    }
    if masks:
        out["mask"] = np.stack(keep["mask"])
    if privileged:
        out["privileged"] = np.stack(keep["privileged"])
        out["depth"] = np.stack(keep["depth"])
    return out


@torch.no_grad()
def encode(encoder: Any, frames: np.ndarray, batch: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Features of ``frames`` (N, 3L, H, W) uint8 through a frozen encoder.

    Returns
    -------
    (z, h): z (N, d) what the policy sees (φ(f(x)) of :class:`omcrl.models.artifact.FrozenEncoder`); h (N, d_f)
    f's tanh outputs (for :func:`saturated_share`).
    """
    zs, hs = [], []
    hook_out: list[torch.Tensor] = []
    handle = encoder.f.register_forward_hook(lambda _m, _i, o: hook_out.append(o))
    try:
        for i in range(0, len(frames), batch):
            x = torch.from_numpy(np.ascontiguousarray(frames[i : i + batch]))
            zs.append(encoder(x).float().numpy())
            hs.append(hook_out.pop().float().numpy())
    finally:
        handle.remove()
    return np.concatenate(zs), np.concatenate(hs)


def mmd_rbf(x: np.ndarray, y: np.ndarray, bandwidth: float | None = None, max_n: int = 2000, seed: int = 0) -> float:
    """Squared MMD between samples x (n, d) and y (m, d) with kernel exp(-|a-b|²/(2σ²)) (biased estimate).

    σ defaults to the median pairwise distance of the pooled samples; at most ``max_n`` rows of each are used
    (drawn with ``seed``). 0 when x and y are the same sample; grows as the distributions part.
    """
    rng = np.random.default_rng(seed)
    x = x[rng.permutation(len(x))[:max_n]] if len(x) > max_n else x
    y = y[rng.permutation(len(y))[:max_n]] if len(y) > max_n else y
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    pooled = np.concatenate([x, y])
    d2 = _sqdist(pooled, pooled)
    if bandwidth is None:
        off = d2[np.triu_indices(len(pooled), 1)]
        med = float(np.median(off)) if off.size else 1.0
        bandwidth = float(np.sqrt(med / 2.0)) if med > 0 else 1.0
    k = np.exp(-d2 / (2.0 * bandwidth**2))
    n = len(x)
    kxx, kyy, kxy = k[:n, :n], k[n:, n:], k[:n, n:]
    return float(max(0.0, kxx.mean() + kyy.mean() - 2.0 * kxy.mean()))


def frechet_distance(x: np.ndarray, y: np.ndarray) -> float:
    """Fréchet distance |μx − μy|² + tr(Σx + Σy − 2(ΣxΣy)^½) between Gaussians fitted to x (n, d) and y (m, d)."""
    from scipy import linalg

    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    mx, my = x.mean(0), y.mean(0)
    cx, cy = np.atleast_2d(np.cov(x, rowvar=False)), np.atleast_2d(np.cov(y, rowvar=False))
    covmean = linalg.sqrtm(cx @ cy)
    if np.iscomplexobj(covmean):
        covmean = covmean.real  # tiny imaginary parts from numerical error
    d = float(((mx - my) ** 2).sum() + np.trace(cx + cy - 2.0 * covmean))
    return max(0.0, d)


def saturated_share(h: np.ndarray, threshold: float = SATURATION) -> float:
    """Fraction of tanh outputs with |h| > ``threshold`` (h: (N, d) in [-1, 1])."""
    return float((np.abs(h) > threshold).mean())


def feature_shift(encoder: Any, frames_ref: np.ndarray, frames_other: np.ndarray) -> dict[str, float]:
    """Shift of ``encoder``'s features from ``frames_ref`` to ``frames_other`` (both (N, 3L, H, W) uint8).

    Returns ``{"mmd": ..., "frechet": ..., "saturated_ref": ..., "saturated": ..., "n_ref": ..., "n": ...}``.
    """
    z0, h0 = encode(encoder, frames_ref)
    z1, h1 = encode(encoder, frames_other)
    return {
        "mmd": mmd_rbf(z0, z1),
        "frechet": frechet_distance(z0, z1),
        "saturated_ref": saturated_share(h0),
        "saturated": saturated_share(h1),
        "n_ref": float(len(z0)),
        "n": float(len(z1)),
    }


def shift_table(encoders: Mapping[str, Any], frames: Mapping[str, np.ndarray], reference: str = "box") -> pd.DataFrame:
    """:func:`feature_shift` of every encoder from ``frames[reference]`` to every setting in ``frames``.

    Parameters
    ----------
    encoders : ``{name: FrozenEncoder}`` (e.g. OMC, CURL, random).
    frames : ``{setting: (N, 3L, H, W) uint8}``, e.g. one entry per scene from :func:`pilot_frames`; the
        reference compared with itself gives the floor (0 MMD by construction; use a second sample of the
        reference scene, e.g. ``"box (other layouts)"``, for the sampling noise floor).

    Returns
    -------
    DataFrame with columns encoder, setting, mmd, frechet, saturated_ref, saturated, n_ref, n.
    """
    rows = []
    for name, enc in encoders.items():
        for setting, fr in frames.items():
            rows.append({"encoder": name, "setting": setting, **feature_shift(enc, frames[reference], fr)})
    return pd.DataFrame(rows)


def probe_across(
    encoder: Any,
    samples: Mapping[str, Mapping[str, np.ndarray]],
    reference: str = "box",
    test_fraction: float = 0.3,
    alpha: float | None = None,
    seed: int = 0,
) -> pd.DataFrame:
    """The linear probe fitted in ``reference`` and tested in every setting: does the encoder's geometry carry over?

    Parameters
    ----------
    encoder : a frozen encoder (``FrozenEncoder`` or a random one) taking the stacks of ``samples``.
    samples : ``{setting: pilot_samples(..., privileged=True)}``; must hold ``reference``.
    reference : the setting the probes are fitted in (its episodes split: ``test_fraction`` held out).
    alpha : ridge penalty; None chooses it per target by cross-validation grouped by episode.

    Returns
    -------
    DataFrame ``setting, target, r2, n``: held-out R² per target of :data:`omcrl.pretrain.probe.TARGETS` in each
    setting (the reference's held-out episodes first). R² below 0 means worse than predicting the mean.
    """
    from sklearn.metrics import r2_score

    if reference not in samples:
        raise KeyError(f"probe_across: reference setting {reference!r} not in samples {sorted(samples)}")
    missing = [k for k, v in samples.items() if "privileged" not in v or "depth" not in v]
    if missing:
        raise KeyError(f"probe_across: settings {missing} lack 'privileged'/'depth' (pilot_samples(privileged=True))")

    def xy(sample: Mapping[str, np.ndarray], idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        z, _ = encode(encoder, sample["rgb"][idx])
        return z.astype(np.float64), probe_targets(sample["privileged"][idx], sample["depth"][idx])

    ref = samples[reference]
    test_eps, _ = split_episodes(np.unique(ref["episode"]), test_fraction, np.random.default_rng(seed))
    is_test = np.isin(ref["episode"], test_eps)
    x_tr, y_tr = xy(ref, np.flatnonzero(~is_test))
    models = fit_probes(x_tr, y_tr, ref["episode"][~is_test], alpha)
    tests = [(reference, ref, np.flatnonzero(is_test))]
    tests += [(k, v, np.arange(len(v["rgb"]))) for k, v in samples.items() if k != reference]
    rows = []
    for setting, sample, idx in tests:
        x, y = xy(sample, idx)
        for i, (t, m) in enumerate(zip(TARGETS, models)):
            rows.append({"setting": setting, "target": t, "r2": float(r2_score(y[:, i], m.predict(x))), "n": len(x)})
    return pd.DataFrame(rows)


class _FixedFeatures(torch.nn.Module):
    """Stands in for a frozen encoder: returns the same feature vector z (d,) for every input stack."""

    def __init__(self, z: np.ndarray) -> None:
        super().__init__()
        self.z = torch.as_tensor(np.asarray(z, np.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.z.expand(x.shape[0], -1)


def with_fixed_features(policy: Any, z: np.ndarray) -> Any:
    """A copy of a frozen-encoder policy (``ours``, ``curl``, ...) whose visual features are always ``z`` (d,).

    With ``z`` the mean box feature, the policy keeps its state inputs (velocity, attitude, goal vector) but
    sees one typical box view whatever the camera shows: does goal seeking survive without vision, and how much
    of the success in a scene comes from seeing? Raises ``ValueError`` for policies without a frozen encoder.
    """
    import copy

    feats = policy.agent.features
    if getattr(feats, "kind", None) != "student":
        raise ValueError(f"with_fixed_features: needs a frozen-encoder policy, got features {feats.kind!r}")
    z = np.asarray(z, np.float32).reshape(-1)
    if z.shape[0] != feats.enc_dim:
        raise ValueError(f"with_fixed_features: z has {z.shape[0]} values, the policy's features {feats.enc_dim}")
    out = copy.copy(policy)
    out.agent = copy.deepcopy(policy.agent)
    out.agent.features.__dict__["encoder"] = _FixedFeatures(z)
    out.name = f"{policy.name}+fixed-features"
    out.checkpoint = ""  # not the file's policy any more: no evaluation cache may take it for it
    return out


def _sqdist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aa = (a * a).sum(1)[:, None]
    bb = (b * b).sum(1)[None, :]
    return np.maximum(aa + bb - 2.0 * a @ b.T, 0.0)
