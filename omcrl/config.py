"""Configuration: one dataclass per stage, YAML presets, validation and overrides.

Every field carries its allowed range or choices in ``metadata`` so a bad value is rejected with an error
naming the field, the value and what is allowed, before any work starts. Presets live in
``omcrl/presets/{smoke,quick,paper}.yaml`` and list only the fields that differ from the defaults below.

Example
-------
>>> cfg = load_config("quick", overrides=["env.image_size=64", "pretrain.mask_prob=0.3"])
>>> cfg.env.image_size
64
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import os
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from omcrl.scenes import PAPER_SUITE, SCENE_SPECS, STRESS_SCENES, SUITES, families, scene_id
from omcrl.utils.errors import ConfigError
from omcrl.utils.io import atomic_write_text
from omcrl.utils.precision import PRECISIONS

PRESETS = ("smoke", "quick", "paper")
PRESET_DIR = Path(__file__).parent / "presets"
ROOT_ENV = "OMCRL_ROOT"


def project_root() -> Path:
    """The folder that relative ``results_dir`` and ``data.file`` paths are taken from.

    ``$OMCRL_ROOT`` when set; else the repository this package was installed from (editable install or a
    checkout: the folder holding ``pyproject.toml`` beside ``omcrl/``); else the current directory. So a
    notebook run from ``notebooks/`` and the CLI run from the repository root read and write the same files.
    """
    env = os.environ.get(ROOT_ENV)
    if env:
        return Path(env).expanduser().resolve()
    repo = Path(__file__).resolve().parent.parent
    if (repo / "pyproject.toml").is_file():
        return repo
    return Path.cwd().resolve()


def resolve_path(path: str | Path) -> Path:
    """``path`` if absolute, else ``project_root() / path``."""
    p = Path(path).expanduser()
    return p if p.is_absolute() else project_root() / p


def _f(
    default: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    choices: tuple | None = None,
    doc: str = "",
    execution: bool = False,
    **kw: Any,
) -> Any:
    """Declare a dataclass field with validation metadata (inclusive bounds ``lo``/``hi``, or ``choices``).

    ``execution``: the field says where or how fast work runs (devices, threads, workers, checkpoint cadence, a
    file's location), not what it computes, so it never enters a run's identity (:func:`section_identity`).
    """
    md = {"lo": lo, "hi": hi, "choices": choices, "doc": doc, "execution": execution}
    if isinstance(default, (list, dict, tuple)) and not isinstance(default, tuple):
        return field(default_factory=lambda d=default: type(d)(d), metadata=md, **kw)
    return field(default=default, metadata=md, **kw)


@dataclass
class EnvConfig:
    """The simulated flight task (paper V-A, V-D). Units: metres, seconds, radians unless stated."""

    scene: str = _f(
        PAPER_SUITE[0],
        doc="scene id (box-v2, furniture-v1, ...) or family (its latest version), stored as the id; omcrl.scenes",
    )
    image_size: int = _f(64, lo=16, hi=512, doc="square camera image side (px)")
    frame_stack: int = _f(3, lo=1, hi=16, doc="L, frames per observation stack")
    control_hz: float = _f(10.0, lo=1.0, hi=100.0, doc="control (and render) rate (Hz)")
    max_steps: int = _f(400, lo=1, hi=100000, doc="truncation horizon (steps); paper H_max = 5000")
    arena_half: float = _f(8.0, lo=2.0, hi=100.0, doc="arena is [-a, a]^2 (m)")
    altitude: float = _f(1.0, lo=0.2, hi=5.0, doc="fixed flight altitude (m)")
    drone_radius: float = _f(0.15, lo=0.01, hi=1.0, doc="collision sphere radius (m)")
    goal_radius: float = _f(0.3, lo=0.01, hi=5.0, doc="success when distance to goal <= this (m)")
    goal_distance: tuple[float, float] = _f((4.0, 10.0), doc="sampled start-goal straight distance range (m)")
    start_yaw_noise: float = _f(0.8, lo=0.0, hi=3.1416, doc="start yaw = bearing to goal +- U(this) (rad)")
    max_speed: float = _f(1.5, lo=0.05, hi=10.0, doc="|vx|, |vy| command limit (m/s)")
    max_yaw_rate: float = _f(1.5, lo=0.05, hi=10.0, doc="|wz| command limit (rad/s)")
    velocity_tau: float = _f(0.2, lo=0.0, hi=5.0, doc="first-order velocity response time constant (s)")
    max_accel: float = _f(4.0, lo=0.1, hi=100.0, doc="linear acceleration limit (m/s^2)")
    fov_deg: float = _f(82.6, lo=10.0, hi=170.0, doc="camera field of view (deg), DJI Tello")
    near: float = _f(0.05, lo=0.001, hi=1.0, doc="camera near plane (m)")
    far: float = _f(20.0, lo=1.0, hi=1000.0, doc="camera far plane; depth is clipped to it (m)")
    n_obstacles: int = _f(0, lo=0, hi=400, doc="obstacle count; 0 means the scene's default")
    layout_every: int = _f(1, lo=1, hi=10**9, doc="episodes per generated layout (start/goal change every episode)")
    progress: str = _f(
        "difference",
        choices=("difference", "literal"),
        doc="progress reward: 0.1(d_{t-1}-d_t) (potential-based) or the paper's 0.1(d_init-d_t)",
    )
    progress_scale: float = _f(0.1, lo=0.0, hi=100.0, doc="progress reward coefficient")
    goal_reward: float = _f(10.0, doc="terminal reward on success")
    collision_penalty: float = _f(-1.0, doc="terminal reward on collision or leaving the arena")
    step_penalty_horizon: int = _f(0, lo=0, hi=1000000, doc="H_max in -1/H_max per step; 0 means max_steps")
    grid_resolution: float = _f(0.1, lo=0.01, hi=1.0, doc="occupancy grid cell (m) for planners and SPL")
    renderer: str = _f(
        "auto",
        choices=("auto", "tiny", "egl"),
        doc="camera renderer: TinyRenderer (CPU), PyBullet's EGL plugin (GPU), or auto (EGL with a CUDA GPU)",
    )


@dataclass
class DataConfig:
    """Trajectory collection for upstream pretraining (paper IV-B)."""

    scene: str = _f(PAPER_SUITE[0], doc="scene the data is flown in: an id or a family, as env.scene")
    episodes: int = _f(60, lo=1, hi=1000000, doc="episodes to collect")
    n_envs: int = _f(2, lo=1, hi=64, doc="parallel environments")
    mix: dict = _f(
        {"pilot": 0.7, "random": 0.3, "policy": 0.0},
        doc="proportions of sources: scripted pilot, random exploration, a given policy",
    )
    pilot_noise: float = _f(0.3, lo=0.0, hi=2.0, doc="std of Gaussian action noise on the scripted pilot")
    detour_prob: float = _f(0.1, lo=0.0, hi=1.0, doc="chance per pilot episode of a detour (a turn in place)")
    random_corr: float = _f(0.9, lo=0.0, hi=0.9999, doc="AR(1) correlation of random exploration actions")
    max_steps: int = _f(200, lo=1, hi=100000, doc="cap on steps per collected episode")
    file: str = _f(
        "data/{preset}/box-seed{seed}.h5",
        doc="HDF5 path; {preset} and {seed} are substituted (a location: the data's content is fingerprinted "
        "instead). The collection is seeded by the training seed, so each seed has its own file; a path without "
        "{seed} is shared by every seed and holds the data of the seed that collected it first",
        execution=True,
    )
    look: str = _f(
        "own",
        choices=("own", "randomized"),
        doc="own: the scene's look; randomized: a random generic look per layout (a deviation, docs/method.md)",
    )
    policy: str = _f(
        "none",
        choices=("none", "oracle"),
        doc="who flies the 'policy' share of data.mix: none (a policy passed to collect.run) or oracle (this "
        "config's oracle at its seed, trained in box; the data then differs per seed and gets a file of its own)",
    )


# Encoders made without data or training (controls): ``random`` keeps f and φ as pretraining initialises them at the
# seed; ``blind`` zeroes every weight, so the features are 0 whatever the camera shows.
UNTRAINED_ENCODERS = ("random", "blind")


@dataclass
class PretrainConfig:
    """Upstream masked contrastive learning (paper IV-B, V-D)."""

    method: str = _f(
        "omc",
        choices=("omc", "curl", "curl_cons", *UNTRAINED_ENCODERS),
        doc="objective; random / blind: no training, f and phi at their initialisation / constant zero features "
        "(the controls ours-random and ours-blind)",
    )
    crop_from: int = _f(72, lo=16, hi=512, doc="stored image size (px); equals env.image_size of the data")
    crop_to: int = _f(64, lo=16, hi=512, doc="random-crop size (px) fed to the encoder")
    batch_size: int = _f(32, lo=1, hi=4096, doc="B, sequences per batch")
    seq_len: int = _f(16, lo=2, hi=256, doc="T, observation stacks per sequence")
    feature_dim: int = _f(384, lo=8, hi=4096, doc="d, latent size")
    proj_hidden: int = _f(384, lo=8, hi=4096, doc="hidden width of projection phi")
    use_projection: bool = _f(True, doc="False gives the 'w/o phi' ablation")
    transformer_blocks: int = _f(2, lo=1, hi=24, doc="blocks in xi")
    transformer_ffn: int = _f(768, lo=8, hi=16384, doc="FFN hidden width in xi")
    dual_transformer: bool = _f(False, doc="momentum xi_k on the key side (ablation 'dualT')")
    mask_prob: float = _f(0.5, lo=0.0, hi=1.0, doc="rho_m, Bernoulli masking probability")
    batch_negatives: bool = _f(True, doc="also use other sequences of the batch as negatives (see DEVIATIONS)")
    temperature: float = _f(0.07, lo=1e-4, hi=10.0, doc="tau in InfoNCE")
    momentum: float = _f(0.05, lo=0.0, hi=1.0, doc="m in theta_k <- m*theta + (1-m)*theta_k")
    lr_encoder: float = _f(1e-3, lo=0.0, hi=1.0, doc="Adam lr for f and phi")
    lr_transformer: float = _f(2e-3, lo=0.0, hi=1.0, doc="peak Adam lr for xi")
    warmup_steps: int = _f(6000, lo=0, hi=10000000, doc="linear warm-up then inverse-sqrt decay for xi")
    iterations: int = _f(2000, lo=1, hi=100000000, doc="optimisation steps")
    cons_stride: int = _f(1, lo=1, hi=100, doc="CURL-cons: step gap between the two consecutive stacks")
    seq_stride: int = _f(
        1, lo=1, hi=100, doc="OMC: env steps between consecutive stacks of a sequence (1 = consecutive, the paper)"
    )
    color_jitter: float = _f(
        0.0,
        lo=0.0,
        hi=0.9,
        doc="OMC: per-view colour gains in [1-s, 1+s] (query and keys jittered differently; a deviation, §3); 0 off",
    )
    checkpoint_every: int = _f(200, lo=1, hi=100000000, doc="iterations between checkpoints", execution=True)
    num_threads: int = _f(2, lo=1, hi=256, doc="torch intra-op threads", execution=True)
    device: str = _f(
        "auto",
        choices=("auto", "cpu", "cuda"),
        doc="where the learner runs: CUDA when available (auto), or cpu / cuda; not part of a run's identity",
        execution=True,
    )
    precision: str = _f(
        "fp32",
        choices=PRECISIONS,
        doc="fp32, bf16 (autocast forward passes; weights, optimiser and loss in fp32) or auto (bf16 where the "
        "hardware runs it natively); the resolved value is part of the run's identity (omcrl.utils.precision)",
    )


@dataclass
class GuidanceConfig:
    """The decaying KL term towards a guide (paper IV-C, eq. 8; V-D: α from 0.95, decayed linearly): the weight α's
    schedule, the KL scale β, and the std given to a deterministic (planner) guide. A student's settings are in
    ``rl``, the oracle's own in ``oracle``, so that changing one never changes the other."""

    alpha_schedule: str = _f("linear", choices=("linear", "exp", "fixed", "none"))
    alpha_start: float = _f(0.95, lo=0.0, hi=1.0)
    alpha_decay_steps: int = _f(100000, lo=1, hi=10**10, doc="linear: steps to reach 0")
    alpha_exp_factor: float = _f(0.95, lo=0.0, hi=1.0, doc="exp: multiply every alpha_exp_every steps")
    alpha_exp_every: int = _f(1000, lo=1, hi=10**9)
    beta: float = _f(1.0, lo=0.0, hi=1000.0, doc="KL scale")
    guide_std: float = _f(0.2, lo=1e-4, hi=10.0, doc="std given to a deterministic (planner) guide")


@dataclass
class OracleConfig(GuidanceConfig):
    """The oracle teacher's own guidance (a kit deviation, docs/method.md): its PPO is pulled early towards
    the privileged Hybrid APF through the same decaying KL term a student has towards the oracle. Its PPO budget
    and settings are ``rl``'s; only the guidance is its own."""

    guide: str = _f("apf", choices=("apf", "none"), doc="'apf': Hybrid APF on the true map; 'none': pure PPO (paper)")


# The guidance fields a student (``rl``) and the oracle (``oracle``) each have: what oracle_config swaps in.
GUIDANCE_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(GuidanceConfig))


@dataclass
class RLConfig(GuidanceConfig):
    """Downstream PPO with optional guidance (paper IV-C, V-D): a student's (and, but for its guidance in
    ``oracle``, the oracle's)."""

    total_steps: int = _f(200000, lo=1, hi=10**10, doc="environment steps over all envs")
    n_envs: int = _f(2, lo=1, hi=256, doc="parallel environments")
    horizon: int = _f(128, lo=1, hi=100000, doc="rollout steps per env between updates")
    buffer_size: int = _f(10240, lo=1, hi=10**8, doc="transitions per update (horizon * n_envs when 0)")
    minibatch: int = _f(1024, lo=1, hi=10**7)
    epochs: int = _f(3, lo=1, hi=100)
    lr: float = _f(3e-4, lo=0.0, hi=1.0, doc="initial lr, decays linearly to 0")
    gamma: float = _f(0.99, lo=0.0, hi=1.0)
    gae_lambda: float = _f(0.95, lo=0.0, hi=1.0)
    clip: float = _f(0.2, lo=0.0, hi=10.0)
    value_coef: float = _f(0.5, lo=0.0, hi=100.0)
    entropy_coef: float = _f(0.0, lo=0.0, hi=10.0)
    max_grad_norm: float = _f(0.5, lo=0.0, hi=1000.0)
    hidden: int = _f(256, lo=8, hi=8192, doc="width of the two actor/critic layers")
    init_log_std: float = _f(-0.5, lo=-10.0, hi=2.0)
    checkpoint_every: int = _f(20480, lo=1, hi=10**10, doc="env steps between checkpoints", execution=True)
    num_threads: int = _f(1, lo=1, hi=256, doc="torch intra-op threads while the envs step (rollouts)", execution=True)
    device: str = _f(
        "auto",
        choices=("auto", "cpu", "cuda"),
        doc="where the networks run: CUDA when available (auto), or cpu / cuda. An execution setting: not part "
        "of a run's identity (a run may resume on another device)",
        execution=True,
    )
    precision: str = _f(
        "fp32",
        choices=PRECISIONS,
        doc="fp32, bf16 (autocast in the PPO updates' forward and backward passes; weights, optimiser, loss and "
        "inference in fp32) or auto (bf16 where the hardware runs it natively); the resolved value is part of the "
        "run's identity and is stored in the policy file (omcrl.utils.precision)",
    )
    update_threads: int = _f(
        0,
        lo=0,
        hi=256,
        doc="torch intra-op threads during PPO updates, when the env workers sleep; 0: one per core. An "
        "execution setting like the machine: not part of a run's identity (results are bit-identical for a "
        "fixed count, and differ in rounding between counts)",
        execution=True,
    )


@dataclass
class EvalConfig:
    """Evaluation harness (paper V-B, VI-A)."""

    episodes: int = _f(50, lo=1, hi=100000, doc="episodes per scene; paper: 200")
    scenes: list = _f(
        [*PAPER_SUITE, *STRESS_SCENES],
        doc="scenes to evaluate (ids or families): the paper's four, then furniture-v0's unseen room as a stress test",
    )
    seed_offset: int = _f(1_000_000, lo=0, hi=10**9, doc="evaluation seeds start here, disjoint from training")
    success_threshold_os: float = _f(0.5, lo=0.0, hi=10.0, doc="OS radius (m)")
    workers: int = _f(
        0,
        lo=0,
        hi=256,
        doc="processes running evaluation episodes in parallel; 0: one per core (results do not depend on it)",
        execution=True,
    )
    lanes: int = _f(
        8,
        lo=1,
        hi=64,
        doc="envs each evaluation process steps in lock-step with one batched policy forward per step "
        "(planners: always 1); a batched forward rounds differently, so rows can differ from lanes=1 "
        "(2 of 600 episode outcomes on the seed-1 quick runs); part of the cache key",
    )
    look: str = _f(
        "",
        doc="render every evaluated scene of another family in this scene's look (an appearance swap of obstacles "
        "and surroundings, e.g. box-v2: the unseen layouts in the training look); '': each scene's own look. Part of "
        "the cache key (as the swap's disturbance)",
    )


@dataclass
class SweepConfig:
    """Ablation sweeps (paper VI-C; :mod:`omcrl.pipeline.sweep`): budgets of the runs a sweep trains."""

    rl_steps: int = _f(
        0,
        lo=0,
        hi=10**10,
        doc="env steps of each sweep run (0: rl.total_steps); the α decay is scaled by the same ratio",
    )
    pretrain_iterations: int = _f(0, lo=0, hi=10**9, doc="pretraining iterations of sweep encoders (0: as pretrain)")
    storage: str = _f(
        "",
        doc="where jobs on a cluster without a shared filesystem exchange runs, data and logs: a folder every node "
        "reaches or an fsspec URI (s3://bucket/prefix); '' = none (docs/cluster.md)",
    )


@dataclass
class Config:
    """Everything a run needs. ``seed`` is explicit: the same seed gives the same result on the CPU."""

    preset: str = _f("quick", choices=PRESETS)
    seed: int = _f(0, lo=0, hi=2**31 - 1, doc="seed of a single run (the CLI's --seed)")
    seeds: list = _f([0], doc="training seeds of a comparison grid (Table I, sweeps); paper: [0, 1, 2]")
    results_dir: str = _f("results", doc="root of results/<preset>/...")
    env: EnvConfig = field(default_factory=EnvConfig)
    data: DataConfig = field(default_factory=DataConfig)
    pretrain: PretrainConfig = field(default_factory=PretrainConfig)
    rl: RLConfig = field(default_factory=RLConfig)
    oracle: OracleConfig = field(default_factory=OracleConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)

    @property
    def results_root(self) -> Path:
        """``results_dir`` as an absolute path (a relative one is taken from :func:`project_root`)."""
        return resolve_path(self.results_dir)

    @property
    def run_root(self) -> Path:
        """``<project root>/results/<preset>`` (absolute; see :func:`project_root`)."""
        return self.results_root / self.preset

    @property
    def data_path(self) -> Path:
        """The pretraining data file: ``data.file`` with ``{preset}`` and ``{seed}`` substituted, absolute (see
        :func:`project_root`)."""
        path = resolve_path(self.data.file.format(preset=self.preset, seed=self.seed))
        if self.data.look != "own":  # another look is other data: never the same file as the default's
            path = path.with_name(f"{path.stem}-{self.data.look}{path.suffix}")
        if self.data.policy == "oracle":  # flown partly by this seed's oracle: one file per seed, whatever the path
            per_seed = "" if "{seed}" in self.data.file else f"-seed{self.seed}"
            path = path.with_name(f"{path.stem}-oracle{per_seed}{path.suffix}")
        return path

    def with_seed(self, seed: int) -> Config:
        """A copy of this config for one training seed (``seed`` set, everything else equal)."""
        import copy

        out = copy.deepcopy(self)
        out.seed = int(seed)
        return validate(out)

    def with_suite(self, suite: str) -> Config:
        """A copy of this config that trains in ``suite``'s box and evaluates in its scenes (and the stress scenes),
        as :func:`omcrl.scenes.suite_overrides` says; ``"v1"`` reproduces the v1 suite's runs."""
        import copy

        if suite not in SUITES:
            raise ConfigError(f"suite: got {suite!r}, expected one of {list(SUITES)}")
        out = copy.deepcopy(self)
        out.env.scene = out.data.scene = SUITES[suite][0]
        out.eval.scenes = [*SUITES[suite], *STRESS_SCENES]
        return validate(out)

    def with_overrides(self, overrides: list[str]) -> Config:
        """A copy of this config with ``'section.field=value'`` overrides applied (as ``--set`` does)."""
        import copy

        out = copy.deepcopy(self)
        apply_overrides(out, list(overrides))
        return validate(out)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# ---------------------------------------------------------------- validation
def show(value: Any) -> str:
    """``repr`` with numpy scalars and arrays as plain Python numbers (numpy 2 prints ``np.float64(3.0)``)."""

    def plain(v: Any) -> Any:
        if hasattr(v, "tolist") and type(v).__module__ == "numpy":
            return v.tolist()
        if isinstance(v, (list, tuple)):
            return type(v)(plain(x) for x in v)
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return repr(plain(value))


def _check_value(path: str, f: dataclasses.Field, value: Any) -> Any:
    """Coerce ``value`` to the field's type and check its bounds; raise ConfigError naming ``path``."""
    md = f.metadata
    tp = f.type if not isinstance(f.type, str) else _resolve_type(f.type)
    origin = typing.get_origin(tp)
    try:
        if tp is bool:
            if isinstance(value, str):
                if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError
                value = value.lower() in ("true", "1", "yes")
            elif not isinstance(value, (bool, int)):
                raise ValueError
            value = bool(value)
        elif tp is int:
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ValueError
            value = int(value)
        elif tp is float:
            if isinstance(value, bool):
                raise ValueError
            value = float(value)
            if not math.isfinite(value):
                raise ValueError
        elif tp is str:
            if not isinstance(value, str):
                raise ValueError
        elif origin is tuple:
            if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
                raise ValueError
            value = tuple(float(v) for v in value)
            if not all(math.isfinite(v) for v in value):
                raise ValueError
        elif tp is list or origin is list:
            if isinstance(value, str):
                value = [v.strip() for v in value.split(",") if v.strip()]
            value = list(value)
        elif tp is dict or origin is dict:
            if not isinstance(value, dict):
                raise ValueError
    except (TypeError, ValueError):
        raise ConfigError(f"config field '{path}': got {show(value)}, expected {_type_name(tp)}") from None
    if origin is tuple and value[0] > value[1]:
        raise ConfigError(f"config field '{path}': got {show(value)}, expected (min, max) with min <= max")
    lo, hi, choices = md.get("lo"), md.get("hi"), md.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"config field '{path}': got {show(value)}, allowed values are {list(choices)}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ConfigError(f"config field '{path}': got {show(value)}, allowed range is [{lo}, {hi}]")
    return value


def _type_name(tp: Any) -> str:
    if typing.get_origin(tp) is tuple:
        return "a pair of finite numbers (min, max)"
    name = getattr(tp, "__name__", str(tp))
    return "a finite number" if name == "float" else name


@functools.cache
def _field_types() -> dict[str, Any]:
    """Each annotation string of this module's dataclass fields (``from __future__ import annotations`` keeps them
    strings) mapped to its type, resolved once by ``typing.get_type_hints``."""
    out: dict[str, Any] = {}
    for cls in [v for v in globals().values() if isinstance(v, type) and dataclasses.is_dataclass(v)]:
        hints = typing.get_type_hints(cls)
        for f in fields(cls):
            out.setdefault(f.type, hints[f.name])
    return out


def _resolve_type(name: str) -> Any:
    """The type of a field annotated ``name`` (a string under postponed annotations)."""
    types = _field_types()
    if name not in types:
        raise ConfigError(f"config: no field of omcrl.config is annotated {name!r}")
    return types[name]


# Fields that moved, for the error a config file written before the move gets (a run's saved config.yaml).
MOVED = {"rl.oracle_guide": "oracle.guide"}


def _apply(obj: Any, values: dict, prefix: str = "") -> None:
    """Set ``values`` (nested dict) on dataclass ``obj``, validating each field; unknown names are errors."""
    by_name = {f.name: f for f in fields(obj)}
    for key, val in values.items():
        path = f"{prefix}{key}"
        if key not in by_name:
            moved = f" (it is now '{MOVED[path]}')" if path in MOVED else ""
            raise ConfigError(f"config field '{path}' does not exist{moved}; known fields: {sorted(by_name)}")
        cur = getattr(obj, key)
        if dataclasses.is_dataclass(cur):
            if not isinstance(val, dict):
                raise ConfigError(f"config section '{path}': got {val!r}, expected a mapping of fields")
            _apply(cur, val, prefix=f"{path}.")
        else:
            setattr(obj, key, _check_value(path, by_name[key], val))


def validate(cfg: Config) -> Config:
    """Check every field of ``cfg`` and the cross-field rules; return it unchanged or raise ConfigError."""

    def walk(obj: Any, prefix: str) -> None:
        for f in fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                setattr(obj, f.name, _check_value(f"{prefix}{f.name}", f, v))

    walk(cfg, "")
    if not cfg.eval.scenes:
        raise ConfigError(f"config field 'eval.scenes': got [], expected at least one of {list(SCENE_SPECS)}")
    cfg.eval.scenes = list(dict.fromkeys(_scene_id("eval.scenes", s) for s in cfg.eval.scenes))
    if cfg.eval.look:
        cfg.eval.look = _scene_id("eval.look", cfg.eval.look)
    cfg.data.scene = _scene_id("data.scene", cfg.data.scene)
    try:
        seeds = [int(v) for v in cfg.seeds]
        if not seeds or any(v < 0 or v != float(w) for v, w in zip(seeds, cfg.seeds)) or len(set(seeds)) < len(seeds):
            raise ValueError
    except (TypeError, ValueError):
        raise ConfigError(
            f"config field 'seeds': got {cfg.seeds!r}, expected a non-empty list of distinct integers >= 0"
        ) from None
    cfg.seeds = seeds
    mix = cfg.data.mix
    try:
        weights = {k: float(v) for k, v in mix.items()}
        if isinstance(mix, dict) and any(isinstance(v, bool) for v in mix.values()):
            raise ValueError
    except (TypeError, ValueError):
        weights = None
    if (
        weights is None
        or set(mix) - {"pilot", "random", "policy"}
        or any(not math.isfinite(v) or v < 0 for v in weights.values())
    ):
        raise ConfigError(
            f"config field 'data.mix': got {show(mix)}, expected non-negative numbers for 'pilot', 'random', 'policy'"
        )
    if sum(weights.values()) <= 0:
        raise ConfigError(f"config field 'data.mix': got {show(mix)}, weights must not all be zero")
    if cfg.data.policy != "none" and weights.get("policy", 0.0) <= 0:
        raise ConfigError(
            f"config field 'data.policy': got {cfg.data.policy!r}, but data.mix gives the 'policy' share no weight "
            f"({show(mix)}); set e.g. data.mix={{pilot: 0.4, random: 0.2, policy: 0.4}}"
        )
    if not str(cfg.results_dir).strip():
        raise ConfigError("config field 'results_dir': got '', expected a folder (default 'results')")
    try:
        cfg.data.file.format(preset=cfg.preset, seed=cfg.seed)
    except (KeyError, IndexError, ValueError) as e:
        raise ConfigError(
            f"config field 'data.file': got {show(cfg.data.file)}, the only placeholders allowed are {{preset}} and "
            f"{{seed}} ({e!r})"
        ) from None
    if cfg.pretrain.crop_to > cfg.pretrain.crop_from:
        raise ConfigError(
            f"config field 'pretrain.crop_to': got {cfg.pretrain.crop_to}, must be <= "
            f"pretrain.crop_from ({cfg.pretrain.crop_from})"
        )
    if cfg.rl.minibatch > cfg.rl.buffer_size:
        raise ConfigError(
            f"config field 'rl.minibatch': got {cfg.rl.minibatch}, must be <= rl.buffer_size ({cfg.rl.buffer_size})"
        )
    validate_env(cfg.env)
    return cfg


def _scene_id(path: str, name: Any) -> str:
    """The canonical id of a scene name (``furniture`` -> ``furniture-v2``), or a ConfigError naming ``path``."""
    try:
        return scene_id(name)
    except ValueError:
        raise ConfigError(
            f"config field '{path}': got {show(name)}, expected a scene id {list(SCENE_SPECS)} or a family "
            f"{list(families())} (its latest version)"
        ) from None


def validate_env(env: EnvConfig, prefix: str = "env.") -> EnvConfig:
    """Cross-field rules of the env config (the env checks them too, so a direct ``make_env`` call fails early).

    Start and goal are drawn ``goal_distance`` apart inside the arena with clearance from its edge; a minimum
    distance beyond 80% of the arena's side can rarely or never be placed, and fails at reset otherwise.
    """
    env.scene = _scene_id(f"{prefix}scene", env.scene)
    lo, hi = env.goal_distance
    reach = 0.8 * 2.0 * env.arena_half
    if lo <= env.goal_radius or lo > reach or hi > 2.0 * math.sqrt(2.0) * env.arena_half:
        raise ConfigError(
            f"config field '{prefix}goal_distance': got {show((lo, hi))}, the minimum must lie in "
            f"({env.goal_radius}, {reach:.1f}] m and the maximum be <= {2 * math.sqrt(2) * env.arena_half:.1f} m "
            f"(arena_half {env.arena_half} m)"
        )
    return env


# ---------------------------------------------------------------- loading
def parse_override(text: str) -> tuple[list[str], Any]:
    """``'env.image_size=64'`` -> (['env', 'image_size'], 64). Values are parsed as YAML scalars/lists."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected 'section.field=value'")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError as e:
        first = str(e).splitlines()[0]
        raise ConfigError(f"override {text!r}: the value is not valid YAML ({first})") from None
    return key.strip().split("."), value


def apply_overrides(cfg: Config, overrides: list[str]) -> None:
    """Set each ``'section.field=value'`` of ``overrides`` on ``cfg`` in place, each value checked as its field
    says (validate the whole config afterwards)."""
    for text in overrides:
        keys, val = parse_override(text)
        nested: dict = {}
        cur = nested
        for k in keys[:-1]:
            cur = cur.setdefault(k, {})
        cur[keys[-1]] = val
        _apply(cfg, nested)


def load_config(
    preset: str = "quick", overrides: list[str] | dict | None = None, path: str | Path | None = None
) -> Config:
    """Build a validated Config from a preset, an optional YAML file and ``field=value`` overrides.

    Parameters
    ----------
    preset : one of ``smoke``, ``quick``, ``paper``.
    overrides : ``["env.image_size=64", ...]`` or a nested dict ``{"env": {"image_size": 64}}``.
    path : a YAML file applied after the preset (for example a saved ``config.yaml`` of a run).
    """
    if preset not in PRESETS:
        raise ConfigError(f"preset: got {preset!r}, allowed values are {list(PRESETS)}")
    cfg = Config(preset=preset)
    preset_file = PRESET_DIR / f"{preset}.yaml"
    _apply(cfg, _read_yaml(preset_file))
    cfg.preset = preset
    if path is not None:
        _apply(cfg, _read_yaml(Path(path)))
    if isinstance(overrides, dict):
        _apply(cfg, overrides)
    else:
        apply_overrides(cfg, overrides or [])
    if cfg.preset != preset:
        # The preset names the results folder: relabelling smoke budgets as paper results must not happen.
        raise ConfigError(
            f"config field 'preset': got {cfg.preset!r} from a config file or override, but the preset is {preset!r}; "
            f"choose the preset with --preset {cfg.preset}"
        )
    return validate(cfg)


@functools.lru_cache(maxsize=256)
def _parse_yaml(text: str) -> Any:
    # Keyed by the file's text, so an edited file is parsed again. A sweep's plan loads the preset and its configs
    # for every job: about 1,800 loads of a few distinct files in one summary --readme (68.3 -> 64.4 s with this).
    return yaml.safe_load(text) or {}


def _read_yaml(p: Path) -> dict:
    if not p.exists():
        raise ConfigError(f"config file {p} does not exist")
    if not p.is_file():
        raise ConfigError(f"config file {p} is not a file")
    try:
        data = copy.deepcopy(_parse_yaml(p.read_text(encoding="utf-8")))
    except UnicodeDecodeError:
        raise ConfigError(f"config file {p} is not a text file (expected YAML)") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        what = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ConfigError(f"config file {p} is not valid YAML{where}: {what}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"config file {p}: expected a mapping at top level, got {type(data).__name__}")
    return data


def save_config(cfg: Config, directory: str | Path) -> Path:
    """Write the resolved config as ``config.yaml`` in ``directory`` (atomically) and return its path."""

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = d / "config.yaml"
    atomic_write_text(out, yaml.safe_dump(_plain(cfg.to_dict()), sort_keys=False))
    return out


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


def _declared_default(f: dataclasses.Field) -> Any:
    return f.default_factory() if f.default is dataclasses.MISSING else f.default  # type: ignore[misc]


def field_default(section: Any, name: str) -> Any:
    """The declared default of field ``name`` of a config section (a class or an instance)."""
    for f in fields(section):
        if f.name == name:
            return _declared_default(f)
    raise ConfigError(f"{getattr(section, '__name__', type(section).__name__)} has no field {name!r}")


def overrides_from_config(cfg: Any) -> list[str]:
    """``"section.field=value"`` for every field of ``cfg`` that differs from its preset's defaults."""
    base = load_config(cfg.preset).to_dict()

    def diff(a: dict, b: dict, prefix: str) -> typing.Iterator[str]:
        for k, v in a.items():
            if isinstance(v, dict) and isinstance(b.get(k), dict) and k not in ("mix",):
                yield from diff(v, b[k], f"{prefix}{k}.")
            elif v != b.get(k):
                val = list(v) if isinstance(v, tuple) else v
                yield f"{prefix}{k}={json.dumps(val)}"

    return list(diff(cfg.to_dict(), base, ""))


def section_identity(section: Any, **resolved: Any) -> dict:
    """The identity of a config section: every field whose value differs from its default, less the fields
    declared execution-only (``_f(..., execution=True)``).

    This is the one rule every run and cache key follows. A field added later at its default changes no key; a
    changed field always does. ``resolved`` replaces values that the machine decides before they are compared
    (``renderer="tiny"`` for ``auto``, ``precision="fp32"``): an ``auto`` default is never a resolved value, so a
    resolved field is in the identity whatever the machine, and two machines share a key exactly when they
    resolve alike.

    Returns
    -------
    ``{field: value}`` in declaration order, tuples as lists (JSON-able).
    """
    if not dataclasses.is_dataclass(section):
        raise TypeError(f"section_identity: expected a config section (a dataclass), got {type(section).__name__}")
    unknown = set(resolved) - {f.name for f in fields(section)}
    if unknown:
        raise ConfigError(f"section_identity: {type(section).__name__} has no field(s) {sorted(unknown)}")
    out = {}
    for f in fields(section):
        if f.metadata.get("execution"):
            continue
        value = resolved.get(f.name, getattr(section, f.name))
        if _plain(value) != _plain(_declared_default(f)):
            out[f.name] = _plain(value)
    return out


def config_hash(section: Any) -> str:
    """Short stable hash of a config section (or dict), for caching finished artifacts."""
    import hashlib
    import json

    d = dataclasses.asdict(section) if dataclasses.is_dataclass(section) else section
    return hashlib.sha256(json.dumps(_plain(d), sort_keys=True).encode()).hexdigest()[:12]
