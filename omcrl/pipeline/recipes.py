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
from omcrl.config import Config, ConfigError
from omcrl.rl.methods import encoder_config, encoder_path, get_method, oracle_path, planner_factory, pretrain_command
from omcrl.rl.policy import CheckpointError
from omcrl.rl.train import Result, train_oracle, train_pixel, train_student


def pretrain_method(cfg: Config, method: str, *, progress: bool = True) -> Any:
    """Pretrain (or find) the frozen encoder of ``method`` at ``cfg.seed``; returns the PretrainResult."""
    return pretrain.run(encoder_config(cfg, method), progress=progress)


def train_method(
    cfg: Config,
    method: str,
    *,
    progress: bool = True,
    overwrite: bool = False,
    make_env: Callable[[int], Any] | None = None,
    oracle_cfg: Config | None = None,
) -> Result:
    """Train one learned method of the comparison at ``cfg.seed`` (skip if finished, resume if interrupted).

    Prerequisites are found, not trained: a frozen encoder must have been pretrained
    (:func:`pretrain_method`) and a method guided by the oracle needs the oracle's run finished: the oracle of
    ``oracle_cfg`` when given (an ablation that changes the student's α schedule keeps the comparison's oracle),
    else of ``cfg``. A missing one
    raises :class:`CheckpointError` naming the file and the command that makes it, before anything is trained.
    """
    spec = get_method(method)
    if not spec.learned:
        raise ConfigError(f"method {method!r} is a planner: it is not trained (evaluate it directly)")
    if spec.features == "oracle":
        return train_oracle(cfg, name=spec.name, make_env=make_env, overwrite=overwrite, progress=progress)
    oracle = oracle_path(oracle_cfg or cfg) if spec.guide == "oracle" else None
    enc = encoder_path(cfg, spec) if spec.features == "frozen" else None
    # Every missing prerequisite at once, with its command (not one now and the next after 30 minutes).
    needs = [
        (oracle, "oracle checkpoint", f"python -m omcrl train --method oracle --preset {cfg.preset} --seed {cfg.seed}"),
        (enc, f"{spec.name} encoder", pretrain_command(cfg, spec) if enc is not None else ""),
    ]
    missing = [(p, what, cmd) for p, what, cmd in needs if p is not None and not p.exists()]
    if missing:
        raise CheckpointError(
            "; ".join(f"{what} {p} does not exist" for p, what, _ in missing)
            + "; run first: "
            + " && ".join(cmd for _, _, cmd in missing)
        )
    planner = planner_factory(cfg, spec.guide)
    common = {"name": spec.name, "planner_factory": planner, "make_env": make_env, "overwrite": overwrite}
    if enc is not None:
        return train_student(cfg, enc, oracle, progress=progress, **common)
    return train_pixel(cfg, oracle, progress=progress, **common)
