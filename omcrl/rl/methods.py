"""The methods of the paper's comparison (Table I, V-C): what each one is and where its runs live.

Each method is a :class:`MethodSpec`: which features its policy sees (privileged depth, a frozen pretrained
encoder, or a pixel encoder trained end to end), which encoder pretraining it needs, and which guide pulls it
early through the decaying KL term. This module answers identity questions only (a method's encoder, its
oracle, the ``final.pt`` of its finished run); training one is :func:`omcrl.pipeline.recipes.train_method`,
with the same env-step budget, PPO settings and seed for every method.

| method | features | encoder | guide |
| --- | --- | --- | --- |
| ``oracle`` | depth + privileged state | — (trained) | Hybrid APF (``oracle.guide``) |
| ``ours`` | frozen f+φ | OMC | the oracle |
| ``ours-noOT`` | frozen f+φ | OMC | none |
| ``curl`` | frozen f | CURL (no φ) | none |
| ``curl-phi`` | frozen f+φ | CURL with φ | none |
| ``ppo`` | f trained end to end | — | none |
| ``npe`` | f trained end to end | — | local APF on the depth camera (non-expert), fixed std ``rl.guide_std`` |
| ``npe-expert`` | f trained end to end | — | Hybrid APF on the true map (an expert), fixed std (not a Table I row) |
| ``npe-ot`` | f trained end to end | — | the oracle |
| ``ours-lapf`` | frozen f+φ | OMC | local APF on the depth camera, as NPE (control row: encoder vs guide) |
| ``ours-random`` | frozen f+φ at initialisation | none (control) | the oracle |
| ``ours-blind`` | constant 0 features (control) | none | the oracle |
| ``hybrid-apf`` | privileged map | — | (planner, not learned) |
| ``hybrid-apf-perceptive`` | depth camera map | — | (planner, not learned) |
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from omcrl import planners, pretrain
from omcrl.config import Config, ConfigError
from omcrl.rl.policy import load_policy
from omcrl.rl.train import Result, oracle_run, policy_run, train_oracle, visuomotor_parts
from omcrl.rl.train import train as train_loop
from omcrl.runs import Run


@dataclass(frozen=True)
class MethodSpec:
    """One method of the comparison.

    Attributes
    ----------
    name : the kit's name (run folders, CLI ``--method``, table rows).
    label : the paper's name in tables and figures.
    features : the method's kind, a key of :data:`RECIPES`: ``oracle`` | ``frozen`` | ``pixel`` | ``planner``.
    encoder : pretraining overrides for a frozen encoder (``{"method": "curl", "use_projection": False}``).
    guide : the guide of a student: ``oracle`` | a planner guide of :data:`omcrl.planners.GUIDES` (``local-apf``,
        ``apf``) | None. The oracle has none here: its own guide is ``oracle.guide``, with its own schedule in
        ``cfg.oracle`` (:func:`omcrl.rl.train.oracle_config`).
    privileged : uses inputs a real robot does not have (true map or depth + obstacle vectors).
    description : one line for ``--help``.
    ablation : a variant for the ablations (VI-C), not a row of Table I.
    control : a control of the kit (issue 75: ``ours-random``, ``ours-blind``): a row of the Table I grid and of the
        ledger's ``controls`` family, not of the paper's comparison that the notebooks train and a bundle holds.
    """

    name: str
    label: str
    features: str
    encoder: dict = field(default_factory=dict)
    guide: str | None = None
    privileged: bool = False
    description: str = ""
    ablation: bool = False
    control: bool = False

    @property
    def recipe(self) -> Recipe:
        """How a method of this kind is trained and flown (:data:`RECIPES`, by ``features``)."""
        return RECIPES[self.features]

    @property
    def learned(self) -> bool:
        return self.recipe.learned


METHODS: dict[str, MethodSpec] = {
    m.name: m
    for m in (
        MethodSpec("oracle", "Oracle", "oracle", privileged=True,
                   description="privileged PPO teacher on depth + state (upper bound)"),
        MethodSpec("ours", "Ours", "frozen", {"method": "omc"}, guide="oracle",
                   description="OMC-RL: frozen masked-contrastive encoder, oracle-guided PPO"),
        MethodSpec("ours-noOT", "Ours w/o OT", "frozen", {"method": "omc"},
                   description="OMC encoder, PPO without the oracle teacher"),
        MethodSpec("npe", "NPE", "pixel", guide="local-apf",
                   description="end-to-end PPO from RGB guided early by a local APF on depth (non-expert)"),
        MethodSpec("npe-ot", "NPE w/ OT", "pixel", guide="oracle",
                   description="end-to-end PPO from RGB guided early by the oracle"),
        # The control that splits ours vs npe (encoder and guide both differ) into an encoder and a guide effect.
        MethodSpec("ours-lapf", "Ours w/ NPE guide", "frozen", {"method": "omc"}, guide="local-apf",
                   description="control: OMC encoder guided early by NPE's local APF (non-expert), fixed std"),
        # Controls (declared in the ledger's controls family before they flew): what the masked contrastive stage
        # adds over its own initialisation, and what sight adds over the state pathway.
        MethodSpec("ours-random", "Ours w/ random encoder", "frozen", {"method": "random"}, guide="oracle",
                   control=True, description="control: ours on a frozen, randomly initialised f+phi (no pretraining)"),
        MethodSpec("ours-blind", "Ours blind", "frozen", {"method": "blind"}, guide="oracle", control=True,
                   description="control: ours with constant visual features (state pathway only)"),
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
    if not spec.recipe.pretrained:
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
    if guide not in planners.GUIDES:
        return None
    name, identity = planners.GUIDES[guide]

    def factory() -> Any:
        return planners.make_planner(name, cfg.env)

    factory.__name__ = identity
    return factory


def final_policy_path(cfg: Config, method: str) -> Path | None:
    """``final.pt`` of a learned method's finished run at ``cfg.seed``, or None when it is not there.

    The run is derived from the current config and upstream artifacts exactly as its recipe trains it
    (:meth:`Recipe.run`), so only a run of this very configuration is found.
    """
    spec = get_method(method)
    run = spec.recipe.run(cfg, spec)
    p = None if run is None else run.dir / "final.pt"
    return p if p is not None and p.exists() else None


def training_runs(cfg: Config, methods: list[str] | None = None, seeds: list[int] | None = None) -> dict:
    """``{method: {seed: run folder}}`` of the finished training runs of learned methods at ``seeds``."""
    out: dict[str, dict[int, Path]] = {}
    for m in methods or [n for n in TABLE1_METHODS if METHODS[n].learned]:
        for s in seeds if seeds is not None else cfg.seeds:
            p = final_policy_path(cfg.with_seed(s), m)
            if p is not None:
                out.setdefault(m, {})[s] = p.parent
    return out


# ---------------------------------------------------------------- recipes: one per kind of method
@dataclass(frozen=True)
class Need:
    """An upstream artifact a method needs before it trains: its role (``oracle`` | ``encoder``), the file, what it
    is (for messages), and the command that makes it."""

    role: str
    path: Path
    what: str
    command: str


class Recipe:
    """How one kind of method (``MethodSpec.features``) is trained and flown; template methods in the manner of
    gym-pybullet-drones, so a new kind is one subclass and one :func:`register_recipe` call.

    Every question that depends on the kind is asked here: its prerequisites (:meth:`needs`), its run identity
    (:meth:`run`), training (:meth:`train`), the agent it flies (:meth:`make_agent`) and what its training job adds
    to a sweep's job identity (:meth:`job_identity`).
    """

    kind: ClassVar[str] = ""
    learned: ClassVar[bool] = True  # trained (a run with ``final.pt``); a planner is not
    pretrained: ClassVar[bool] = False  # flies a frozen encoder pretrained before it (a pretraining job first)
    camera: ClassVar[bool] = False  # sees the camera through an encoder (Grad-CAM, disturbance tests)
    teacher: ClassVar[bool] = False  # its run is the oracle that guided students need (one shared sweep job)

    def needs(self, cfg: Config, spec: MethodSpec) -> list[Need]:
        """The upstream artifacts, whether present or not: the oracle when the guide is the oracle, and the frozen
        encoder of a pretrained kind."""
        out = []
        if spec.guide == "oracle":
            cmd = f"python -m omcrl train --method oracle --preset {cfg.preset} --seed {cfg.seed}"
            out.append(Need("oracle", oracle_path(cfg), "oracle checkpoint", cmd))
        if self.pretrained:
            out.append(Need("encoder", encoder_path(cfg, spec), f"{spec.name} encoder", pretrain_command(cfg, spec)))
        return out

    def _path(self, needs: list[Need], role: str) -> Path | None:
        return next((n.path for n in needs if n.role == role), None)

    def run(self, cfg: Config, spec: MethodSpec) -> Run | None:
        """The run this method trains into at ``cfg.seed``, or None while a prerequisite is missing (a policy's
        run identity takes its upstream files' digests)."""
        needs = self.needs(cfg, spec)
        if any(not n.path.exists() for n in needs):
            return None
        enc = self._path(needs, "encoder")
        oracle = self._path(needs, "oracle")
        return policy_run(cfg, spec.name, enc, oracle, planner_factory(cfg, spec.guide))

    def train(
        self,
        cfg: Config,
        spec: MethodSpec,
        needs: list[Need],
        *,
        name: str,
        make_env: Callable[[int], Any] | None = None,
        **common: Any,
    ) -> Result:
        """Train this kind on its prerequisites ``needs`` (present: :func:`omcrl.pipeline.train_method` checked them);
        skip if finished, resume if interrupted; ``common``: the training loop's ``overwrite``, ``progress``,
        ``callbacks``. By default a visuomotor policy on the needed encoder (none: end to end) and guide."""
        enc, oracle = self._path(needs, "encoder"), self._path(needs, "oracle")
        parts = visuomotor_parts(cfg, enc, oracle, name=name, planner_factory=planner_factory(cfg, spec.guide),
                                 make_env=make_env)  # fmt: skip
        return train_loop(cfg, **parts, **common)

    def make_agent(self, cfg: Config, spec: MethodSpec, path: Path | None = None) -> Any:
        """The agent this method flies (:class:`omcrl.agent.Agent`): its policy from ``path`` (default its finished
        run's ``final.pt``)."""
        path = path or final_policy_path(cfg, spec.name)
        if path is None:
            raise FileNotFoundError(f"no finished {spec.name} run for seed {cfg.seed}; train it first")
        return load_policy(path, name=spec.name)

    def job_identity(self, cfg: Config) -> dict:
        """What a sweep's training job of this kind adds to its identity beyond the method's config."""
        return {}


class OracleRecipe(Recipe):
    """The privileged teacher: PPO on depth and privileged state, its own run identity (:func:`oracle_run`)."""

    kind = "oracle"
    teacher = True

    def run(self, cfg: Config, spec: MethodSpec) -> Run | None:
        return oracle_run(cfg)

    def train(self, cfg: Config, spec: MethodSpec, needs: list[Need], **common: Any) -> Result:
        return train_oracle(cfg, **common)

    def make_agent(self, cfg: Config, spec: MethodSpec, path: Path | None = None) -> Any:
        return load_policy(path or oracle_path(cfg), spec.name, expect_kind="oracle")


class FrozenRecipe(Recipe):
    """A student on a frozen pretrained encoder (ours, curl, ...): PPO on [f(rgb), state]."""

    kind = "frozen"
    pretrained = True
    camera = True


class PixelRecipe(Recipe):
    """A pixel encoder trained end to end with the policy (ppo, npe, npe-ot)."""

    kind = "pixel"
    camera = True

    def job_identity(self, cfg: Config) -> dict:
        return {"pixel": {"crop": cfg.pretrain.crop_to, "feature_dim": cfg.pretrain.feature_dim}}


class PlannerRecipe(Recipe):
    """A classical planner (Hybrid APF, privileged or perceptive): nothing to train, nothing to find."""

    kind = "planner"
    learned = False

    def needs(self, cfg: Config, spec: MethodSpec) -> list[Need]:
        return []

    def run(self, cfg: Config, spec: MethodSpec) -> Run | None:
        return None

    def train(self, cfg: Config, spec: MethodSpec, needs: list[Need], **common: Any) -> Result:
        raise ConfigError(f"method {spec.name!r} is a planner: it is not trained (evaluate it directly)")

    def make_agent(self, cfg: Config, spec: MethodSpec, path: Path | None = None) -> Any:
        return planners.make_planner(spec.name, cfg.env)


RECIPES: dict[str, Recipe] = {}


def register_recipe(recipe: Recipe) -> Recipe:
    """Add a kind of method: ``MethodSpec(features=recipe.kind)`` then trains and flies through ``recipe``."""
    if not recipe.kind:
        raise ValueError(f"{type(recipe).__name__}.kind is empty")
    if recipe.kind in RECIPES and type(RECIPES[recipe.kind]) is not type(recipe):
        raise ValueError(f"a recipe for kind {recipe.kind!r} exists already ({type(RECIPES[recipe.kind]).__name__})")
    RECIPES[recipe.kind] = recipe
    return recipe


def register_method(spec: MethodSpec) -> MethodSpec:
    """Add a method (one row of :data:`METHODS`); its ``features`` must name a registered recipe."""
    if spec.features not in RECIPES:
        raise ConfigError(f"method {spec.name!r}: features {spec.features!r} has no recipe; known: {list(RECIPES)}")
    if spec.name in METHODS and METHODS[spec.name] != spec:
        raise ValueError(f"method {spec.name!r} exists already with another spec")
    METHODS[spec.name] = spec
    return spec


for _recipe in (OracleRecipe(), FrozenRecipe(), PixelRecipe(), PlannerRecipe()):
    register_recipe(_recipe)
