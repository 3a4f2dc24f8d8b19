"""Evaluation stage: find trained policies, evaluate them (and Hybrid APF) in every scene, write Table I.

``evaluate_stage(cfg)`` is the CLI stage ``python -m omcrl evaluate --preset P``. It evaluates every finished
policy under ``<run_root>/runs/rl/<method>-<key>/seed<k>/final.pt`` plus the privileged :class:`HybridAPF` baseline
in ``cfg.eval.scenes`` for ``cfg.eval.episodes`` episodes each (the same evaluation seeds for every method),
and writes under ``<run_root>/``::

    eval/<method>/seed<k>/<scene>-<key>/     run.json + episodes.csv, one row per episode (cache; key: checkpoint,
                                             env config, seeds, behaviour versions)
    tables/<name>_episodes.csv     all episodes of this evaluation
    tables/<name>.csv              method × scene metrics (long form: NE OS SR SPL CR TTS episodes)
    tables/<name>.md               the paper's Table I layout (methods × (scene, metric))

Evaluating one (method, scene) pair is cached as a run (:func:`cached_episodes`): a finished one of the same key
is read back instead of re-running the episodes, so the notebooks and the CLI share results.
"""

from __future__ import annotations

import json
import shutil
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from omcrl import planners
from omcrl.config import Config
from omcrl.envs.render import env_identity
from omcrl.eval.metrics import format_table, summary_table
from omcrl.eval.runner import EvalPool, evaluate
from omcrl.rl import load_policy
from omcrl.runs import Run, RunConfigMismatch, behaviour, cache_run, find_runs, read_identity
from omcrl.scenes import scene_id, scene_spec
from omcrl.utils.io import atomic_write_text, file_digest

HYBRID_APF = "HybridAPF"
# Planners are evaluated by name (no checkpoint): omcrl.planners.PLANNERS and its aliases.
PLANNER_NAMES = (*planners.ALIASES, *planners.PLANNERS)


@dataclass(repr=False)
class EvalResult:
    """What an evaluation produced: per-episode rows, the metrics table and where they were written."""

    episodes: pd.DataFrame
    table: pd.DataFrame
    paths: dict[str, Path] = field(default_factory=dict)
    wall_time_s: float = 0.0

    def wide(self, decimals: int = 2) -> pd.DataFrame:
        """The paper's Table I layout (:func:`omcrl.eval.format_table`)."""
        return format_table(self.table, decimals)

    def __repr__(self) -> str:  # what the CLI prints: the table by scene, then where it was written
        lines = [f"{len(self.episodes)} episodes in {self.wall_time_s:.0f} s"]
        with pd.option_context("display.width", 200, "display.max_columns", 50):
            for scene in dict.fromkeys(self.table.index.get_level_values("scene")):
                lines += [f"-- {scene}", self.table.xs(scene, level="scene").round(2).to_string(na_rep="–")]
        lines += [f"{k}: {v}" for k, v in self.paths.items()]
        return "\n".join(lines)


def find_policies(cfg: Config) -> dict[str, Path]:
    """``{method: final.pt}`` for every finished RL run at ``cfg.seed`` (``<run_root>/runs/rl/*/seed<k>``).

    The label is the method name; when one method has runs of several configurations, each is labelled
    ``<method>-<key>``.
    """

    runs = [r for r in find_runs(cfg.run_root, "rl") if r["seed"] == cfg.seed and (r["dir"] / "final.pt").exists()]
    count: dict[str, int] = {}
    for r in runs:
        count[r["method"]] = count.get(r["method"], 0) + 1
    return {
        (r["method"] if count[r["method"]] == 1 else f"{r['method']}-{r['key']}"): r["dir"] / "final.pt" for r in runs
    }


def _load(method: str, source: Any) -> tuple[Any, str]:
    """A policy object and a cache key for ``source``: a checkpoint path, a planner name or a policy."""

    if isinstance(source, str) and source in PLANNER_NAMES:
        # Planners are code, not files: their name, with the planners' behaviour version in the cache identity.
        return planners.make_planner(source), source
    if isinstance(source, (str, Path)):
        return load_policy(source, name=method), file_digest(Path(source))
    # An object: only cached under its explicit checkpoint, if it names one.
    ckpt = getattr(source, "checkpoint", "")
    return source, (file_digest(Path(ckpt)) if ckpt and Path(ckpt).is_file() else "")


def evaluation_identity(
    cfg: Config,
    policy_key: str,
    env: Any,
    episodes: int,
    *,
    planner: bool,
    lanes: int,
    seed_offset: int | None = None,
    disturbance: Mapping[str, Any] | None = None,
) -> dict:
    """The identity of one cached evaluation (``<run_root>/eval/...`` and the disturbance tests alike).

    ``policy_key``: the policy file's digest, or a planner's name; ``env``: the env section it is flown in (its
    scene set), by :func:`~omcrl.envs.render.env_identity`; the episodes, their seeds (``seed_offset``, default
    ``cfg.eval.seed_offset``), the lanes stepped in lock-step (1 for planners), the disturbance, and the
    behaviour versions of the code that decides the episodes (:func:`omcrl.runs.behaviour`).
    """
    return {
        "policy": policy_key,
        "env": env_identity(env),
        "episodes": int(episodes),
        "seed_offset": int(cfg.eval.seed_offset if seed_offset is None else seed_offset),
        "lanes": int(lanes),
        **({"disturbance": dict(disturbance)} if disturbance else {}),
        "versions": behaviour("eval-planner" if planner else "eval-policy"),
    }


EPISODES = "episodes.csv"


def portable_checkpoint(checkpoint: object) -> object:
    """A policy file's path as its run folder names it, ``<method>-<key>/seed<k>`` (the key decides the run, the
    folders above it are this machine's); anything else (a planner's empty path, a bare name) as it is."""
    if not isinstance(checkpoint, str) or "/" not in checkpoint:
        return checkpoint
    p = Path(checkpoint)
    return f"{p.parent.parent.name}/{p.parent.name}"


def _episodes_csv(df: pd.DataFrame) -> str:
    out = df.copy()
    if "trajectory" in out:
        out["trajectory"] = [json.dumps([[round(x, 3), round(y, 3)] for x, y in t]) for t in out["trajectory"]]
    return out.to_csv(index=False)


def _read_episodes(run: Run, rows: int) -> pd.DataFrame | None:
    """The finished evaluation ``run``'s rows, or None when it has none or they cannot be trusted (a warning
    naming the file, then the episodes are flown again): a cache is used only whole, its CSV matching the digest
    and row count ``run.json`` recorded when it was written."""
    try:
        rec = read_identity(run.dir)
    except RunConfigMismatch as e:  # run.json damaged: the record of this cache, nothing else depends on it
        warnings.warn(f"damaged evaluation cache record: {e}; evaluating again", stacklevel=3)
        shutil.rmtree(run.dir)
        return None
    if rec is None or rec.get("key") != run.key or rec.get("rows") != rows:
        return None  # not this evaluation, or never finished
    path = run.finished(EPISODES, again="damaged evaluation cache; evaluating again")
    if path is None:
        return None
    try:
        df = pd.read_csv(path)
    except (OSError, ValueError, UnicodeDecodeError) as e:
        warnings.warn(
            f"{path}: damaged evaluation cache (unreadable, {type(e).__name__}); evaluating again", stacklevel=3
        )
        return None
    if len(df) != rows:
        warnings.warn(
            f"{path}: damaged evaluation cache ({len(df)} rows, expected {rows}); evaluating again", stacklevel=3
        )
        return None
    # CSV writes "" and NaN alike; a planner's empty checkpoint must come back as "", like a fresh row.
    if "checkpoint" in df:
        df["checkpoint"] = ["" if pd.isna(v) else str(v) for v in df["checkpoint"]]
    if "trajectory" in df:
        try:
            df["trajectory"] = [[tuple(p) for p in json.loads(t)] for t in df["trajectory"]]
        except (TypeError, ValueError):
            warnings.warn(f"{path}: damaged evaluation cache (trajectories); evaluating again", stacklevel=3)
            return None
    return df


def cached_episodes(
    folder: Path,
    name: str,
    seed: int,
    identity: dict | None,
    rows: int,
    fly: Callable[[], pd.DataFrame],
    stats: dict[str, int] | None = None,
) -> pd.DataFrame:
    """The ``rows`` episodes of the evaluation ``identity`` (:func:`evaluation_identity`), read from its cache run
    ``<folder>/<name>-<key>/`` (:func:`omcrl.runs.cache_run`) when it finished, else flown by ``fly()`` and kept.

    ``identity`` None: not cached (a policy object without a checkpoint has nothing to key it by). The run is locked
    while it is flown, so two processes never write one cache (:class:`omcrl.runs.RunLocked` names the other).
    ``stats``: ``stats["cached"]`` / ``stats["evaluated"]`` count what was read and what was flown.
    """
    run = cache_run(folder, name, seed, identity) if identity is not None else None
    df = _read_episodes(run, rows) if run is not None else None
    if stats is not None:
        k = "cached" if df is not None else "evaluated"
        stats[k] = stats.get(k, 0) + 1
    if df is not None:
        return df
    if run is None:
        return fly()
    run.claim(overwrite=True)  # a folder of this key that is not a finished cache of it is made again
    try:
        df = fly()
        if "checkpoint" in df:
            # The key holds the policy's digest; its path names this machine's folders, which a cache (copied into
            # a bundle, or made while packing one) outlives. Flown and read back, the rows say the same.
            df = df.assign(checkpoint=df["checkpoint"].map(portable_checkpoint))
        run.finish(_episodes_csv(df), EPISODES, rows=len(df))
    finally:
        run.release()
    return df


def eval_cache_root(cfg: Config) -> Path:
    """``<run_root>/eval``: every evaluation :func:`evaluate_methods` caches, one folder per label."""
    return cfg.run_root / "eval"


def eval_cache_dir(cfg: Config, label: str) -> Path:
    """Where :func:`evaluate_methods` caches ``label``'s episodes at ``cfg.seed``:
    ``<run_root>/eval/<label>/seed<k>``."""
    return eval_cache_root(cfg) / label.replace("/", "_") / f"seed{cfg.seed}"


def look_disturbance(cfg: Config, scene: str) -> dict[str, str] | None:
    """The appearance swap ``cfg.eval.look`` asks for in ``scene``: ``{"appearance": look}`` when the look is another
    family's (the unseen layouts drawn in the training scene's look), None for the scene's own look."""
    look = cfg.eval.look
    if not look or scene_spec(look).family == scene_spec(scene).family:
        return None
    return {"appearance": look}


def evaluate_methods(
    cfg: Config,
    methods: Mapping[str, Any],
    scenes: Sequence[str] | None = None,
    episodes: int | None = None,
    *,
    cache: bool = True,
    progress: bool = False,
    pool: EvalPool | None = None,
    disturbance: Mapping[str, Any] | None = None,
    stats: dict[str, int] | None = None,
) -> pd.DataFrame:
    """Evaluate each method in each scene on the same evaluation seeds; one row per episode.

    Parameters
    ----------
    cfg : env settings (``cfg.env``; the scene is set per evaluation), seeds (``cfg.seed``,
        ``cfg.eval.seed_offset``) and the cache folder ``<run_root>/eval``.
    methods : ``{label: source}``, source = a policy checkpoint path, ``"HybridAPF"`` or a policy object with
        ``act(obs, info)``.
    scenes, episodes : default ``cfg.eval.scenes`` and ``cfg.eval.episodes``.
    cache : read/write the cache run ``<run_root>/eval/<label>/seed<k>/<scene>-<key>/`` (:func:`cached_episodes`),
        the key a hash of :func:`evaluation_identity`: checkpoint content, env config, episode seeds, lanes and the
        behaviour versions of the code that flies them.
    pool : an open :class:`~omcrl.eval.runner.EvalPool` to run episodes in; default: one of
        ``cfg.eval.workers`` processes for this call (in this process when 1). Results do not depend on it.
    disturbance : passed to every env (e.g. ``{"appearance": "box"}``: each scene's layouts in box's look, see
        :class:`omcrl.envs.Disturbance`); part of the cache key, and of the cache file's name. Default: the swap
        ``cfg.eval.look`` asks for in each scene (:func:`look_disturbance`), none when it is empty.
    stats : when given, ``stats["cached"]`` and ``stats["evaluated"]`` count the (method, scene) evaluations read
        from the cache and flown.

    Every method, and every training seed ``cfg.seed``, is evaluated on the same episodes: episode ``i`` resets
    with seed ``cfg.eval.seed_offset + i`` (paired comparisons across methods and seeds).

    Returns
    -------
    DataFrame with the columns of :func:`omcrl.eval.evaluate` (``method`` = label, ``scene``, ``train_seed`` = the
    training seed), methods in the given order, scenes in the given order.
    """
    scenes = [scene_id(s) for s in (scenes if scenes is not None else cfg.eval.scenes)]
    episodes = int(episodes if episodes is not None else cfg.eval.episodes)

    frames = []
    with ExitStack() as stack:
        if pool is None and cfg.eval.workers != 1:  # workers start on the first uncached evaluation
            pool = stack.enter_context(EvalPool(cfg.eval.workers))
        for label, source in methods.items():
            policy, pkey = _load(label, source)
            planner = isinstance(source, str) and source in PLANNER_NAMES
            lanes = cfg.eval.lanes if callable(getattr(policy, "act_batch", None)) else 1
            for scene in scenes:
                env = replace(cfg.env, scene=scene)
                dist = look_disturbance(cfg, scene) if disturbance is None else disturbance
                ident = evaluation_identity(cfg, pkey, env, episodes, planner=planner, lanes=lanes, disturbance=dist)
                tail = "" if not dist else "-" + "-".join(f"{v}" for v in dist.values())

                def fly(policy: Any = policy, label: str = label, scene: str = scene, dist: Any = dist) -> pd.DataFrame:
                    return evaluate(
                        policy,
                        scene,
                        episodes,
                        0,
                        seed_offset=cfg.eval.seed_offset,
                        method=label,
                        progress=progress,
                        workers=pool or 1,
                        lanes=cfg.eval.lanes,
                        config=cfg.env,
                        **({"disturbance": dict(dist)} if dist else {}),
                    )

                df = cached_episodes(
                    eval_cache_dir(cfg, label),
                    scene + tail,
                    cfg.seed,
                    ident if cache and pkey else None,
                    episodes,
                    fly,
                    stats,
                )
                frames.append(df.assign(method=label, scene=scene, train_seed=cfg.seed))
    return pd.concat(frames, ignore_index=True)


def to_markdown(wide: pd.DataFrame, index_name: str = "method") -> str:
    """A GitHub-markdown table of a (possibly two-level-column) frame; no extra dependency."""
    cols = [" ".join(str(c) for c in col) if isinstance(col, tuple) else str(col) for col in wide.columns]
    lines = ["| " + " | ".join([index_name, *cols]) + " |", "|" + "---|" * (len(cols) + 1)]
    for idx, row in wide.iterrows():
        cells = [f"{v:g}" if isinstance(v, float) else str(v) for v in row.tolist()]
        lines.append("| " + " | ".join([str(idx), *cells]) + " |")
    return "\n".join(lines) + "\n"


def scene_cells(rows: pd.DataFrame, scenes: Sequence[str], cell: Callable[[pd.Series], str]) -> str:
    """A markdown table row's cells, one per scene in ``scenes`` order: ``cell`` of ``rows``' row of that scene
    (column ``scene``), empty where it has none."""
    by = rows.set_index("scene")
    return " | ".join(cell(by.loc[s]) if s in by.index else "" for s in scenes)


def write_tables(episodes_df: pd.DataFrame, directory: str | Path, name: str, os_threshold: float = 0.5) -> dict:
    """Write ``<name>_episodes.csv``, ``<name>.csv`` (long metrics) and ``<name>.md`` (Table I layout).

    Returns ``{"episodes": path, "csv": path, "md": path, "table": DataFrame}``.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    table = summary_table(episodes_df, os_threshold=os_threshold)
    paths = {"episodes": d / f"{name}_episodes.csv", "csv": d / f"{name}.csv", "md": d / f"{name}.md"}
    atomic_write_text(paths["episodes"], episodes_df.drop(columns=["trajectory"], errors="ignore").to_csv(index=False))
    atomic_write_text(paths["csv"], table.to_csv())
    n = int(table["episodes"].min()) if len(table) else 0
    head = f"NE (m), OS/SR/CR (%), SPL (0-1), TTS (steps, successful episodes); {n} episodes per cell.\n\n"
    atomic_write_text(paths["md"], head + to_markdown(format_table(table)))
    return {**paths, "table": table}


def evaluate_stage(cfg: Config, *, name: str | None = None, progress: bool = True) -> EvalResult:
    """CLI stage ``evaluate``: all finished oracle/student policies at ``cfg.seed`` + Hybrid APF, all scenes; write
    a one-seed table ``tables/evaluate_seed<k>.{csv,md}`` (default ``name``) and its episodes. Table I itself
    (``tables/table1.*``, over seeds) has one writer, the ``tables`` stage.

    Raises FileNotFoundError when no trained policy exists under ``<run_root>/runs`` (train one first).
    """
    t0 = time.perf_counter()
    policies = find_policies(cfg)
    if not policies:
        raise FileNotFoundError(
            f"no trained policy under {cfg.run_root / 'runs'}/rl/*/seed{cfg.seed}/final.pt; "
            "run the oracle / student stages (or notebooks 03-04) first"
        )
    methods: dict[str, Any] = {**policies, HYBRID_APF: HYBRID_APF}
    df = evaluate_methods(cfg, methods, progress=progress)
    name = name or f"evaluate_seed{cfg.seed}"
    if name.startswith("table1"):
        raise ValueError(f"evaluate: name {name!r} is Table I's; only `python -m omcrl tables` writes table1.*")
    out = write_tables(df, cfg.run_root / "tables", name, cfg.eval.success_threshold_os)
    table = out.pop("table")
    return EvalResult(df, table, out, time.perf_counter() - t0)
