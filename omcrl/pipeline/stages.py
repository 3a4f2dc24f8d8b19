"""Stage functions that put the library together: training a method, pretraining its encoder, collecting with
the oracle, printing the config, drawing a flight log. The CLI finds them through :mod:`omcrl.pipeline.registry`.
"""

from __future__ import annotations

import json
import sys
from typing import Any

import yaml

from omcrl import pretrain
from omcrl.config import Config, ConfigError
from omcrl.data import collect
from omcrl.pipeline.recipes import pretrain_method, train_method
from omcrl.rl.methods import METHODS, oracle_path
from omcrl.rl.policy import load_policy
from omcrl.rl.train import Result
from omcrl.viz.deploy import replay


def print_config(cfg: Config) -> None:
    """Stage ``config``: print the resolved config as YAML (loadable with ``--config``)."""
    plain = json.loads(json.dumps(cfg.to_dict()))  # tuples -> lists, as save_config writes them
    sys.stdout.write(yaml.safe_dump(plain, sort_keys=False))


def replay_stage(cfg: Config, log: str, out: str | None = None) -> str:
    """CLI stage ``replay``: ``python -m omcrl replay LOG [--out PNG]``; returns where the drawing went."""

    try:
        return f"replay: {replay(log, out=out)}"
    except ValueError as e:
        raise ConfigError(str(e)) from None


def train_stage(cfg: Config, method: str | None = None, *, progress: bool = True) -> Result:
    """CLI stage ``train``: ``python -m omcrl train --method <name> --preset P [--seed k]``."""
    if method is None:
        learned = [m for m, s in METHODS.items() if s.learned]
        raise ConfigError(f"stage 'train' needs --method, one of {learned}")
    return train_method(cfg, method, progress=progress)


def oracle_stage(cfg: Config, *, progress: bool = True) -> Result:
    """CLI stage ``oracle``: the same as ``train --method oracle``."""
    return train_method(cfg, "oracle", progress=progress)


def student_stage(cfg: Config, *, progress: bool = True) -> Result:
    """CLI stage ``student``: ``ours`` (``ours-noOT`` with ``rl.alpha_schedule=none``)."""
    return train_method(cfg, "ours-noOT" if cfg.rl.alpha_schedule == "none" else "ours", progress=progress)


def pretrain_stage(cfg: Config, method: str | None = None, *, progress: bool = True) -> Any:
    """CLI stage ``pretrain``: the encoder of ``--method`` (ours, curl, curl-phi, ...), else ``cfg.pretrain``."""
    if method is None:
        return pretrain.pretrain_encoder(cfg, progress=progress)
    return pretrain_method(cfg, method, progress=progress)


def oracle_policy(cfg: Config) -> Any:
    """The act function of this config's trained oracle at ``cfg.seed`` (for ``data.policy=oracle``).

    Raises
    ------
    ConfigError : the oracle is not trained (checked before any episode is flown).
    """
    path = oracle_path(cfg)
    if not path.exists():
        raise ConfigError(
            f"data.policy='oracle': the oracle of this config at seed {cfg.seed} is not trained ({path} does not "
            f"exist); train it first: python -m omcrl oracle --preset {cfg.preset} --seed {cfg.seed}"
        )
    return load_policy(path, "oracle", expect_kind="oracle").act


def collect_stage(cfg: Config, policy: Any = None, *, progress: bool = True) -> collect.CollectResult:
    """CLI stage ``collect``: :func:`omcrl.data.collect.collect_dataset`, with this config's trained oracle flying the
    ``policy`` share when ``data.policy=oracle`` (the data layer takes a policy; finding the oracle is ours)."""
    if policy is None and cfg.data.policy == "oracle":
        policy = oracle_policy(cfg)
    return collect.collect_dataset(cfg, policy, progress=progress)
