"""Upstream pretraining stage: ``pretrain_encoder(cfg) -> PretrainResult`` (paper IV-B, V-D).

Writes under ``results/<preset>/runs/pretrain/<name>/seed<k>/``:

* ``config.yaml``   the resolved configuration
* ``metrics.csv``   tidy rows ``step,metric,value`` (loss, accuracy, lr_encoder, lr_transformer, ...)
* ``checkpoint.pt`` learner, optimiser and RNG states (atomic, every ``checkpoint_every`` iterations)
* ``encoder.pt``    the frozen f + φ artifact (:func:`omcrl.models.load_encoder`)
* ``run.json``      the run's identity; when it finishes, also the encoder's digest, the iterations, the final
                    loss and the dataset it was made of (:meth:`omcrl.runs.Run.finish`, as every RL run). A finished
                    run with the same resolved config and the same data is skipped

An interrupted run resumes from ``checkpoint.pt`` and ends at the same iteration count with the same weights
as an uninterrupted one (all random generators are checkpointed).
"""

from __future__ import annotations

import csv
import json
import logging
import math
import warnings
from contextlib import closing
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import torch

from omcrl.config import UNTRAINED_ENCODERS, Config, PretrainConfig, section_identity
from omcrl.data.collect import collection_env
from omcrl.data.dataset import DatasetError, open_dataset
from omcrl.data.sampler import SequenceSampler
from omcrl.envs.render import env_identity
from omcrl.models.artifact import encoder_payload
from omcrl.pretrain.learner import ContrastiveLearner, objective, transformer_lr_factor
from omcrl.runs import Run, StopAfter, make_run, read_identity
from omcrl.utils.precision import section_precision
from omcrl.utils.runtime import resolve_device, set_threads

log = logging.getLogger(__name__)

_CACHE_BYTES = 256 * 2**20  # cache all frames in RAM below this size


@dataclass
class PretrainResult:
    """What a pretraining run produced."""

    name: str
    run_dir: Path
    encoder_path: Path
    metrics_path: Path
    iterations: int
    final_loss: float
    dataset_fingerprint: str
    skipped: bool = False
    start: int = 0  # the iteration this call began at: a resumed run's checkpoint (its earlier part not timed)


def method_name(p: PretrainConfig) -> str:
    """Run folder name: the objective plus every ablation flag that differs from the paper's OMC setting
    (:meth:`~omcrl.pretrain.learner.Objective.run_name`).

    ``omc``, ``omc-rho0.3``, ``omc-nophi``, ``omc-dualT``, ``omc-seqneg``, ``omc-stride3``, ``curl`` (no φ, as in CURL),
    ``curl-phi``, ``curl_cons``, ``curl_cons-stride3``; the untrained controls ``random`` and ``blind``.
    """
    if p.method in UNTRAINED_ENCODERS:
        return p.method if p.use_projection else f"{p.method}-nophi"
    return objective(p).run_name(p)


def untrained_encoder(cfg: Config, run_rec: Run) -> PretrainResult:
    """The encoder of an untrained control (``pretrain.method`` in :data:`~omcrl.config.UNTRAINED_ENCODERS`), written
    as a finished pretraining run with 0 iterations and no dataset.

    ``random``: f and φ exactly as :func:`pretrain_encoder` initialises them at ``cfg.seed`` before its first
    iteration (the OMC learner's construction under ``torch.manual_seed(cfg.seed)``): what the masked contrastive
    stage starts from. ``blind``: the same architecture with every weight and bias 0, so f's LayerNorm and tanh
    give 0 and φ(0) = 0: (B, d) zeros for any input, a student that flies on its state alone.
    """
    p = cfg.pretrain
    name, out = method_name(p), run_rec.dir
    enc_path = out / "encoder.pt"
    done = read_identity(out) or {}
    if done.get("artifact_digest") and run_rec.finished("encoder.pt") is not None:
        return PretrainResult(name, out, enc_path, out / "metrics.csv", 0, math.nan, "", True)
    with run_rec.claimed(cfg):
        torch.manual_seed(cfg.seed)
        learner = ContrastiveLearner(replace(p, method="omc"), cfg.env.frame_stack)
        if p.method == "blind":
            with torch.no_grad():
                for t in (*learner.f.parameters(), *learner.phi.parameters()):
                    t.zero_()
        run_rec.finish(
            encoder_payload(learner.f, learner.phi, cfg, ""),
            "encoder.pt",
            keep_checkpoint=False,
            iterations=0,
            final_loss=None,
            dataset="",
            dataset_fingerprint="",
        )
    log.info("pretrain %s: untrained encoder written to %s", name, enc_path)
    return PretrainResult(name, out, enc_path, out / "metrics.csv", 0, math.nan, "")


def pretrain_run(cfg: Config) -> Run:
    """The :class:`omcrl.runs.Run` of this pretraining configuration.

    Its identity is the sections it reads, by :func:`~omcrl.config.section_identity`: the pretraining section
    (precision resolved), the data collection section (its file is a location, execution-only) and the env the
    data is flown in (:func:`~omcrl.data.collect.collection_env`). The dataset's content fingerprint is the
    upstream digest; it is checked when a run finishes or resumes (``run.json``, the checkpoint) rather than
    keyed, so the encoder's path is known before the data is collected, and re-collected data retrains the run.
    """
    ident = {
        "pretrain": section_identity(cfg.pretrain, precision=section_precision(cfg.pretrain)),
        "data": section_identity(cfg.data),
        "env": env_identity(collection_env(cfg)),
    }
    return make_run(cfg, "pretrain", method_name(cfg.pretrain), ident)


def run_dir(cfg: Config) -> Path:
    """``<run_root>/runs/pretrain/<method_name>-<key>/seed<k>`` (see :func:`pretrain_run`)."""
    return pretrain_run(cfg).dir


def encoder_path(cfg: Config) -> Path:
    """Where this configuration's frozen encoder is (or will be): ``run_dir(cfg) / "encoder.pt"``."""
    return run_dir(cfg) / "encoder.pt"


def default_dataset_path(cfg: Config) -> Path:
    """``cfg.data.file`` with ``{preset}`` and ``{seed}`` substituted (:attr:`omcrl.config.Config.data_path`)."""
    return cfg.data_path


def _made_of(run: Run, fingerprint: str) -> dict:
    """What a finished encoder or a checkpoint was made of: the run's key and the dataset's fingerprint."""
    return {"key": run.key, "dataset_fingerprint": fingerprint}


def _made_by(record: dict, made_of: dict) -> bool:
    """Does a checkpoint ``record`` say it was made of ``made_of`` (:func:`_made_of`)?"""
    return all(record.get(k) == v for k, v in made_of.items())


def _read_metrics(path: Path, upto: int) -> list[tuple[int, str, float]]:
    if not path.exists():
        return []
    with path.open() as fh:
        return [(int(r["step"]), r["metric"], float(r["value"])) for r in csv.DictReader(fh) if int(r["step"]) <= upto]


def pretrain_encoder(
    cfg: Config,
    dataset_path: str | Path | None = None,
    *,
    progress: bool = True,
    stop_after: int | None = None,
) -> PretrainResult:
    """Train the encoder as configured by ``cfg.pretrain`` on the trajectory file and save the artifact.

    Parameters
    ----------
    cfg : resolved configuration (``cfg.env.frame_stack`` is L; ``cfg.pretrain.crop_from`` must equal the
        dataset's image size).
    dataset_path : HDF5 trajectory file; default ``cfg.data.file`` with ``{preset}`` and ``{seed}`` substituted.
    progress : show progress (:class:`omcrl.utils.progress.Progress`).
    stop_after : stop after this iteration without finishing (simulates an interruption; for tests).
    """
    p = cfg.pretrain
    set_threads(p.num_threads)
    path = Path(dataset_path) if dataset_path is not None else default_dataset_path(cfg)
    name = method_name(p)
    run_rec = pretrain_run(cfg)
    run_rec.check()
    if p.method in UNTRAINED_ENCODERS:
        return untrained_encoder(cfg, run_rec)
    done, ds = _finished_or_data(cfg, run_rec, path)
    if done is not None:
        return done
    out, fp = run_rec.dir, ds.fingerprint
    enc_path, metrics_path = out / "encoder.pt", out / "metrics.csv"
    made_of = _made_of(run_rec, fp)
    state = run_rec.load("pretraining checkpoint")  # before anything is written: a damaged one is refused
    callbacks = () if stop_after is None else (StopAfter(stop_after),)
    with closing(ds), run_rec.claimed(cfg):
        torch.manual_seed(cfg.seed)
        # The objective, chosen once: OMC reconstructs masked latents of a sequence; CURL matches two views of a
        # stack, and sees as many stacks per iteration as OMC (B·T), so the two compare at equal data throughput.
        obj = objective(p)
        L = cfg.env.frame_stack
        learner = ContrastiveLearner(p, L).to(resolve_device(p.device))
        learner.precision = section_precision(p)
        opt = torch.optim.Adam(learner.param_groups())
        # Keep all episodes in memory when the frames are small (quick/smoke presets); else stream from disk.
        cache = len(ds) if ds.n_steps * 3 * ds.image_size**2 <= _CACHE_BYTES else 0
        sampler = SequenceSampler(ds, p.batch_size, p.seq_len, L, crop=(p.crop_from, p.crop_to), seed=cfg.seed,
                                  cache_episodes=cache, seq_stride=obj.sequence_stride(p))  # fmt: skip
        gen = torch.Generator().manual_seed(cfg.seed + 1)
        start, rows = _resume(state, made_of, p.iterations, learner, opt, sampler, gen, metrics_path, name)
        it, loss_val = start, float("nan")
        learner.train()
        with run_rec.session(
            total=p.iterations, start=start, unit="it", progress=progress, callbacks=callbacks, digits=None
        ) as s:
            while it < p.iterations:
                it += 1
                lrs = {"lr_encoder": p.lr_encoder}
                for g in opt.param_groups:  # the Transformer warms up (paper V-D); the encoder's rate is fixed
                    if g["name"] == "transformer":
                        g["lr"] = lrs["lr_transformer"] = p.lr_transformer * transformer_lr_factor(it, p.warmup_steps)
                loss, metrics = obj.loss(learner, sampler, gen)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                learner.momentum_update()
                loss_val = metrics["loss"]
                row = {**metrics, **lrs}
                s.log(it, row, 1, loss=f"{loss_val:.3f}", acc=f"{metrics['accuracy']:.2f}")
                # Checkpoints also at the end: the encoder can be rebuilt from the final one.
                if it >= p.iterations or s.due(it - 1, it, p.checkpoint_every):
                    s.checkpoint(it, {"step": it, **made_of, "learner": learner.state_dict(), "optim": opt.state_dict(),
                                      "sampler_rng": json.dumps(sampler.rng.bit_generator.state),
                                      "mask_rng": gen.get_state(), "torch_rng": torch.get_rng_state()})  # fmt: skip
                if not s.keep_going(it, row):
                    break
        if not s.ended:
            return PretrainResult(name, out, enc_path, metrics_path, it, loss_val, fp, start=start)
        if start >= p.iterations:  # resumed from a final checkpoint whose artifact was not written
            loss_val = next((v for _, m, v in reversed(rows) if m == "loss"), float("nan"))
        run_rec.finish(
            encoder_payload(learner.f, learner.phi, cfg, fp),
            "encoder.pt",
            keep_checkpoint=True,
            iterations=p.iterations,
            final_loss=loss_val if math.isfinite(loss_val) else None,  # JSON has no NaN
            dataset=str(path),
            dataset_fingerprint=fp,
        )
    return PretrainResult(name, out, enc_path, metrics_path, p.iterations, loss_val, fp, start=start)


def _finished_or_data(cfg: Config, run_rec: Run, path: Path) -> tuple[PretrainResult | None, Any]:
    """``(result, None)`` when the run is finished on the data at ``path`` (skipped), else ``(None, dataset)``.

    Finished: ``run.json`` holds the digest of the encoder it wrote (:meth:`~omcrl.runs.Run.finish`) and the
    fingerprint of the data it was made of. Without the file, that recorded fingerprint stands in for it (a finished
    run needs its dataset only to notice re-collected data). A finished encoder that changed since it was written is
    not trusted: :meth:`~omcrl.runs.Run.finished` moves it aside with a warning, and the run is made again (from its
    final checkpoint when there is one, else by training)."""
    p = cfg.pretrain
    out, name = run_rec.dir, method_name(p)
    enc_path = out / "encoder.pt"
    done = read_identity(out) or {}
    done = done if done.get("artifact_digest") and enc_path.exists() else None
    if done is not None and not path.exists():
        fp, ds = str(done.get("dataset_fingerprint", "")), None
    else:
        if not path.exists():
            raise DatasetError(
                f"dataset {path}: file does not exist; run first: python -m omcrl collect --preset {cfg.preset}"
                + (f" --seed {cfg.seed}" if cfg.data.policy == "oracle" else "")
            )
        ds = open_dataset(path, image_size=p.crop_from, frame_stack=cfg.env.frame_stack)
        fp = ds.fingerprint
    if done is not None and done.get("dataset_fingerprint") == fp and run_rec.finished("encoder.pt") is not None:
        log.info("pretrain %s: finished run with the same config found in %s, skipping", name, out)
        if ds is not None:
            ds.close()
        loss = done.get("final_loss")
        loss = math.nan if loss is None else loss
        return PretrainResult(name, out, enc_path, out / "metrics.csv", done["iterations"], loss, fp, True), None
    if ds is None:  # the finished run cannot be reused and there is no dataset to train again from
        ds = open_dataset(path, image_size=p.crop_from, frame_stack=cfg.env.frame_stack)
    return None, ds


def _resume(
    state: dict | None,
    made_of: dict,
    iterations: int,
    learner: ContrastiveLearner,
    opt: torch.optim.Optimizer,
    sampler: SequenceSampler,
    gen: torch.Generator,
    metrics_path: Path,
    name: str,
) -> tuple[int, list[tuple[int, str, float]]]:
    """Restore a checkpoint's learner, optimiser and random generators when it was made of this run's key and data:
    ``(start iteration, the metrics rows up to it)``; ``(0, [])`` without one, or with one of other data or code."""
    if state is None:
        return 0, []
    if not (_made_by(state, made_of) and state["step"] <= iterations):
        log.warning(
            "pretrain %s: checkpoint in %s is from other data or code; starting over", name, metrics_path.parent
        )
        return 0, []
    learner.load_state_dict(state["learner"])
    opt.load_state_dict(state["optim"])
    sampler.rng.bit_generator.state = json.loads(state["sampler_rng"])
    gen.set_state(state["mask_rng"])
    torch.set_rng_state(state["torch_rng"])
    start = int(state["step"])
    rows = _read_metrics(metrics_path, start)
    logged = {step for step, _, _ in rows}
    if len(logged) < start:
        msg = (
            f"{metrics_path}: {start - len(logged)} of the {start} iterations before the resume point have "
            "no metrics (the file was deleted or cut); their history is lost, training goes on"
        )
        log.warning("pretrain %s: %s", name, msg)
        warnings.warn(msg, stacklevel=3)
    log.info("pretrain %s: resuming from iteration %d", name, start)
    return start, rows
