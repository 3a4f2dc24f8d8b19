"""What a pretrained encoder learned, as a few numbers a budget ladder can set side by side.

``report.json``, written beside a pretraining run's ``encoder.pt`` (:func:`write_encoder_report`)::

    {"encoder_digest": ...,            the encoder file it describes (a rebuilt encoder gets a new report)
     "reference": "box-v2",            the training scene: the probe is fitted there, the shift measured from there
     "top1": 0.21,                     the pretraining objective's top-1 (OMC: masked queries, CURL: InfoNCE
                                       queries whose most similar key is the positive), mean of the last 10 % of
                                       the iterations' values (each iteration's is over one batch: noisy)
     "probe_r2": {setting: R²},        the linear probe (omcrl.pretrain.probe; fitted on the reference's pilot
                                       frames, held-out episodes) tested in each setting, mean over its targets
     "mmd": {setting: MMD²},           feature shift from the reference (omcrl.interpret.shift.feature_shift)
     "frechet": {setting: distance},
     "episodes": 12}                   pilot episodes per setting (the reference flies twice as many)

The settings are the training scene, a second sample of it on other layouts (the sampling floor of the shift) and
every evaluation scene of ``cfg.eval.scenes`` (:func:`suite_settings`). Frames come from scripted-pilot flights with
fixed seeds (:data:`omcrl.interpret.transfer.PILOT_SEED`), so every encoder of a ladder is measured on the same
frames and the probe on the same held-out episodes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from omcrl.config import Config
from omcrl.interpret.shift import probe_across, shift_table
from omcrl.interpret.transfer import pilot_episodes, setting_samples
from omcrl.models.artifact import load_encoder
from omcrl.runs import metric_series, read_identity
from omcrl.utils.io import atomic_write_text, file_digest

REPORT = "report.json"
ENCODER = "encoder.pt"
# Share of the last pretraining iterations whose top-1 values are averaged (one batch each: noisy).
TOP1_TAIL = 0.1


def suite_settings(cfg: Config) -> tuple[tuple[str, str, None], ...]:
    """``(setting, scene, disturbance)`` of an encoder report: the training scene ``cfg.env.scene``, a second sample
    of it on other layouts, and each evaluation scene of ``cfg.eval.scenes`` other than the training scene."""
    train = cfg.env.scene
    others = [s for s in dict.fromkeys(cfg.eval.scenes) if s != train]
    return ((train, train, None), (f"{train}, other layouts", train, None), *((s, s, None) for s in others))


def final_top1(metrics: str | Path) -> float:
    """Mean ``accuracy`` of the last :data:`TOP1_TAIL` of a pretraining run's iterations (``metrics``: its
    metrics.csv(.gz) or run folder); NaN when the run logged none."""
    series = metric_series(metrics)
    if "accuracy" not in series or not len(series["accuracy"][0]):
        return float("nan")
    steps, values = series["accuracy"]
    tail = steps >= steps[-1] - TOP1_TAIL * (steps[-1] - steps[0])
    return float(np.nanmean(values[tail]))


def encoder_report(
    cfg: Config, run_dir: str | Path, samples: dict[str, dict[str, np.ndarray]] | None = None
) -> dict[str, Any]:
    """The report of module docstring for the pretraining run ``run_dir`` (its ``encoder.pt``, verified against the
    digest its run recorded, and its ``metrics.csv``).

    ``samples``: :func:`omcrl.interpret.transfer.setting_samples` of :func:`suite_settings` when already flown (a
    caller reporting several encoders flies them once); flown here otherwise (quick: about a minute).
    """
    run_dir = Path(run_dir)
    path = run_dir / ENCODER
    encoder = load_encoder(path, cfg.env.image_size, cfg.env.frame_stack)
    settings = suite_settings(cfg)
    reference = settings[0][0]
    if samples is None:
        samples = setting_samples(cfg, settings=settings)
    # One fixed split (seed 0) for every encoder: the ladder's probes are tested on the same held-out episodes.
    probe = probe_across(encoder, samples, reference=reference, seed=0)
    shift = shift_table({"encoder": encoder}, {k: v["rgb"] for k, v in samples.items()}, reference=reference)
    r2 = probe.groupby("setting", sort=False)["r2"].mean()
    return {
        "encoder_digest": file_digest(path),
        "reference": reference,
        "top1": final_top1(run_dir),
        "probe_r2": {k: float(v) for k, v in r2.items()},
        "mmd": {r.setting: float(r.mmd) for r in shift.itertuples()},
        "frechet": {r.setting: float(r.frechet) for r in shift.itertuples()},
        "episodes": pilot_episodes(cfg),
    }


def read_report(run_dir: str | Path) -> dict[str, Any] | None:
    """The ``report.json`` of a pretraining run (or of its record in a grid's data), None when there is none or it
    is not a JSON object."""
    p = Path(run_dir) / REPORT
    try:
        rec = json.loads(p.read_text(encoding="utf-8")) if p.is_file() else None
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) else None


def write_encoder_report(
    cfg: Config, run_dir: str | Path, samples: dict[str, dict[str, np.ndarray]] | None = None
) -> Path:
    """Write ``report.json`` into the pretraining run ``run_dir`` (atomically) unless one for the same encoder file
    (digest) and the same settings is there; returns its path."""
    run_dir = Path(run_dir)
    out = run_dir / REPORT
    have = read_report(run_dir)
    want = (read_identity(run_dir) or {}).get("artifact_digest") or file_digest(run_dir / ENCODER)
    settings = [s for s, _, _ in suite_settings(cfg)]
    if have is not None and have.get("encoder_digest") == want and list(have.get("probe_r2", {})) == settings:
        return out
    atomic_write_text(out, json.dumps(encoder_report(cfg, run_dir, samples), indent=1))
    return out
