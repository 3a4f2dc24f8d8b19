"""Method recipes: train or pretrain one method of the comparison, prerequisites checked first.

The library below answers what a method is and where its runs live (:mod:`omcrl.rl.methods`); a recipe here
puts the trainers together for it: ``train_method(cfg, name)`` trains one at ``cfg.seed`` (or skips it when its
run is finished, or resumes it), with the same env-step budget, PPO settings and seed for every method, and
``pretrain_method`` pretrains (or finds) a frozen encoder.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from omcrl import pretrain
from omcrl.config import Config
from omcrl.rl.methods import Need, encoder_config, get_method
from omcrl.rl.policy import CheckpointError
from omcrl.rl.train import Result


def pretrain_method(cfg: Config, method: str, *, progress: bool = True) -> Any:
    """Pretrain (or find) the frozen encoder of ``method`` at ``cfg.seed``; returns the PretrainResult."""
    return pretrain.pretrain_encoder(encoder_config(cfg, method), progress=progress)


def train_method(
    cfg: Config,
    method: str,
    *,
    progress: bool = True,
    overwrite: bool = False,
    make_env: Callable[[int], Any] | None = None,
    callbacks: tuple[Any, ...] = (),
) -> Result:
    """Train one learned method of the comparison at ``cfg.seed`` (skip if finished, resume if interrupted).

    Prerequisites are found, not trained: a frozen encoder must have been pretrained (:func:`pretrain_method`) and
    a method guided by the oracle needs the oracle's run finished (the oracle of ``cfg``, whose guidance is
    ``cfg.oracle``: a student's ``rl.alpha_*`` do not change it). A missing one raises :class:`CheckpointError`
    naming the file and the command that makes it, before anything is trained.
    ``callbacks``: :class:`omcrl.runs.Callback` s of the training lifecycle (e.g. :class:`omcrl.runs.StopAfter`).
    """
    spec = get_method(method)
    needs = spec.recipe.needs(cfg, spec)
    _require(needs)
    return spec.recipe.train(
        cfg, spec, needs, name=spec.name, make_env=make_env, overwrite=overwrite, progress=progress, callbacks=callbacks
    )


def _require(needs: list[Need]) -> None:
    """Raise :class:`CheckpointError` naming every missing prerequisite at once, with the commands that make them
    (not one now and the next after 30 minutes)."""
    missing = [n for n in needs if not n.path.exists()]
    if missing:
        raise CheckpointError(
            "; ".join(f"{n.what} {n.path} does not exist" for n in missing)
            + "; run first: "
            + " && ".join(n.command for n in missing)
        )
