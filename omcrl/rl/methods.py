"""The methods of the paper's comparison (Table I, V-C): what each one is and where its runs live.

Each method is a :class:`MethodSpec`: which features its policy sees (privileged depth, a frozen pretrained
encoder, or a pixel encoder trained end to end), which encoder pretraining it needs, and which guide pulls it
early through the decaying KL term. This module answers identity questions only (a method's encoder, its
oracle, the ``final.pt`` of its finished run); training one is :func:`omcrl.pipeline.recipes.train_method`,
with the same env-step budget, PPO settings and seed for every method.

| method | features | encoder | guide |
| --- | --- | --- | --- |
| ``oracle`` | depth + privileged state | — (trained) | Hybrid APF (``rl.oracle_guide``) |
| ``ours`` | frozen f+φ | OMC | the oracle |
| ``ours-noOT`` | frozen f+φ | OMC | none |
| ``curl`` | frozen f | CURL (no φ) | none |
| ``curl-phi`` | frozen f+φ | CURL with φ | none |
| ``ppo`` | f trained end to end | — | none |
| ``npe`` | f trained end to end | — | local APF on the depth camera (non-expert), fixed std ``rl.guide_std`` |
| ``npe-expert`` | f trained end to end | — | Hybrid APF on the true map (an expert), fixed std (not a Table I row) |
| ``npe-ot`` | f trained end to end | — | the oracle |
| ``hybrid-apf`` | privileged map | — | (planner, not learned) |
| ``hybrid-apf-perceptive`` | depth camera map | — | (planner, not learned) |
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omcrl import planners, pretrain
from omcrl.config import Config, ConfigError
from omcrl.rl.train import oracle_run, policy_run

# Planner guides: name -> (class in omcrl.planners, the factory name that enters a run's identity). "apf" keeps
# the name its runs had before the non-expert guide existed, so expert-guided runs keep their keys.
PLANNER_GUIDES = {"apf": ("HybridAPF", "hybrid_apf"), "local-apf": ("LocalAPF", "local_apf")}


@dataclass(frozen=True)
class MethodSpec:
    """One method of the comparison.

    Attributes
    ----------
    name : the kit's name (run folders, CLI ``--method``, table rows).
    label : the paper's name in tables and figures.
    features : ``oracle`` | ``frozen`` | ``pixel`` | ``planner``.
    encoder : pretraining overrides for a frozen encoder (``{"method": "curl", "use_projection": False}``).
    guide : ``oracle`` | a planner guide of :data:`PLANNER_GUIDES` (``local-apf``, ``apf``) | None
        (``oracle-config``: the oracle's own ``rl.oracle_guide``).
    privileged : uses inputs a real robot does not have (true map or depth + obstacle vectors).
    description : one line for ``--help``.
    ablation : a variant for the ablations (VI-C), not a row of Table I.
    """

    name: str
    label: str
    features: str
    encoder: dict = field(default_factory=dict)
    guide: str | None = None
    privileged: bool = False
    description: str = ""
    ablation: bool = False

    @property
    def learned(self) -> bool:
        return self.features != "planner"


METHODS: dict[str, MethodSpec] = {
    m.name: m
    for m in (
        MethodSpec("oracle", "Oracle", "oracle", guide="oracle-config", privileged=True,
                   description="privileged PPO teacher on depth + state (upper bound)"),
        MethodSpec("ours", "Ours", "frozen", {"method": "omc"}, guide="oracle",
                   description="OMC-RL: frozen masked-contrastive encoder, oracle-guided PPO"),
        MethodSpec("ours-noOT", "Ours w/o OT", "frozen", {"method": "omc"},
                   description="OMC encoder, PPO without the oracle teacher"),
        MethodSpec("npe", "NPE", "pixel", guide="local-apf",
                   description="end-to-end PPO from RGB guided early by a local APF on depth (non-expert)"),
        MethodSpec("npe-ot", "NPE w/ OT", "pixel", guide="oracle",
                   description="end-to-end PPO from RGB guided early by the oracle"),
        MethodSpec("curl", "CURL", "frozen", {"method": "curl", "use_projection": False},
                   description="frozen CURL encoder (no phi), PPO without guidance"),
        MethodSpec("curl-phi", "CURL w/ phi", "frozen", {"method": "curl", "use_projection": True},
                   description="frozen CURL encoder with projection phi, PPO without guidance"),
        MethodSpec("ppo", "PPO", "pixel",
                   description="end-to-end PPO from RGB, no pretraining, no guidance"),
        MethodSpec("hybrid-apf", "Hybrid APF", "planner", privileged=True,
                   description="A* on the true map + potential field on the true nearest obstacle"),
        MethodSpec("hybrid-apf-perceptive", "Hybrid APF (perceptive)", "planner",
                   description="A* on the map seen by the depth camera + potential field on sensed obstacles"),
        # Ablation variants (VI-C; grids in omcrl.pipeline.grids).
        MethodSpec("ours-noPhi", "Ours w/o phi", "frozen", {"method": "omc", "use_projection": False},
                   guide="oracle", ablation=True, description="ablation: OMC encoder without projection phi"),
        MethodSpec("ours-dualT", "Ours-dualT", "frozen", {"method": "omc", "dual_transformer": True},
                   guide="oracle", ablation=True, description="ablation: OMC with a Transformer on both branches"),
        MethodSpec("npe-expert", "NPE (expert guide)", "pixel", guide="apf", ablation=True,
                   description="NPE guided by Hybrid APF on the true map (an expert; the kit's NPE before v1)"),
        MethodSpec("curl-cons", "CURL-cons", "frozen", {"method": "curl_cons", "use_projection": False},
                   ablation=True, description="ablation: CURL on consecutive stacks (pretrain.cons_stride apart)"),
    )
}  # fmt: skip

# Methods of Table I in the paper's order (the oracle first as the upper bound); ablation variants are not rows.
TABLE1_METHODS = tuple(n for n, s in METHODS.items() if not s.ablation)


def get_method(name: str) -> MethodSpec:
    """The spec of ``name``; a ConfigError lists the known methods otherwise."""
    if name not in METHODS:
        raise ConfigError(f"method: got {name!r}, known methods are {list(METHODS)}")
    return METHODS[name]


def encoder_config(cfg: Config, method: str | MethodSpec) -> Config:
    """``cfg`` with the pretraining overrides of ``method``'s frozen encoder applied (a copy)."""
    spec = get_method(method) if isinstance(method, str) else method
    if spec.features != "frozen":
        raise ConfigError(f"method {spec.name!r} has no pretrained encoder (features: {spec.features})")
    out = copy.deepcopy(cfg)
    for k, v in spec.encoder.items():
        setattr(out.pretrain, k, v)
    return out


def encoder_path(cfg: Config, method: str | MethodSpec) -> Path:
    """Where ``method``'s frozen encoder for ``cfg`` (and ``cfg.seed``) is written by pretraining."""

    return pretrain.encoder_path(encoder_config(cfg, method))


def pretrain_command(cfg: Config, method: str | MethodSpec) -> str:
    """The CLI line that pretrains ``method``'s encoder (for error messages)."""
    spec = get_method(method) if isinstance(method, str) else method
    return f"python -m omcrl pretrain --method {spec.name} --preset {cfg.preset} --seed {cfg.seed}"


def oracle_path(cfg: Config) -> Path:
    """The oracle's ``final.pt`` for ``cfg`` (``cfg.seed``): where ``omcrl.pipeline.train_method(cfg, "oracle")`` writes
    it."""
    return oracle_run(cfg).dir / "final.pt"


def planner_factory(cfg: Config, guide: str | None) -> Callable[[], Any] | None:
    """A zero-argument factory of ``guide``'s planner (its ``__name__`` enters the run's identity), or None
    when the guide is not a planner (``"oracle"``, None)."""
    if guide not in PLANNER_GUIDES:
        return None

    cls = getattr(planners, PLANNER_GUIDES[guide][0])

    def factory() -> Any:
        return cls(cfg.env)

    factory.__name__ = PLANNER_GUIDES[guide][1]
    return factory


def final_policy_path(cfg: Config, method: str, oracle_cfg: Config | None = None) -> Path | None:
    """``final.pt`` of a learned method's finished run at ``cfg.seed``, or None when it is not there.

    The run is derived from the current config and upstream artifacts exactly as
    :func:`omcrl.pipeline.recipes.train_method` derives it, so only a run of this very configuration is found.
    """
    spec = get_method(method)
    if spec.features == "oracle":
        p = oracle_path(cfg)
        return p if p.exists() else None
    oracle = oracle_path(oracle_cfg or cfg) if spec.guide == "oracle" else None
    enc = encoder_path(cfg, spec) if spec.features == "frozen" else None
    if (oracle is not None and not oracle.exists()) or (enc is not None and not enc.exists()):
        return None
    planner = planner_factory(cfg, spec.guide)
    p = policy_run(cfg, spec.name, enc, oracle, planner).dir / "final.pt"
    return p if p.exists() else None


def training_runs(cfg: Config, methods: list[str] | None = None, seeds: list[int] | None = None) -> dict:
    """``{method: {seed: run folder}}`` of the finished training runs of learned methods at ``seeds``."""
    out: dict[str, dict[int, Path]] = {}
    for m in methods or [n for n in TABLE1_METHODS if METHODS[n].learned]:
        for s in seeds if seeds is not None else cfg.seeds:
            p = final_policy_path(cfg.with_seed(s), m)
            if p is not None:
                out.setdefault(m, {})[s] = p.parent
    return out
