"""The CLI's stage table (:data:`STAGES`: ``name -> Stage``: its function, description, outputs and arguments), and
:func:`load_stage`.

Every stage takes the resolved :class:`~omcrl.config.Config` first, so notebooks, tests, sweeps and the CLI run
the same code. A stage's module is imported when the stage runs, not with this table, so ``--help`` and a
stage's first line do not wait for PyTorch and PyBullet to load.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, NamedTuple

from omcrl.config import Config


class Stage(NamedTuple):
    """One stage of the CLI: what runs, what it is, what it writes and what it takes from the command line.

    Attributes
    ----------
    target : ``"module:function"``; the function takes the resolved config first, then ``args`` as keywords.
    description : one line, for ``python -m omcrl --help``.
    outputs : what the stage writes (under ``results/<preset>/`` unless a path is given) and its defaults, for the
        stage's ``--help``.
    args : the keyword arguments the function takes from the command line, by their parser names (``dest``):
        ``sweep``'s ``grid``, ``seeds``, ...; ``method`` for ``--method``.
    preset : the stage needs ``--preset`` (False: it acts on a file named on the command line).
    """

    target: str
    description: str
    outputs: str
    args: tuple[str, ...] = ()
    preset: bool = True


STAGES: dict[str, Stage] = {
    "config": Stage(
        "omcrl.pipeline.stages:print_config",
        "print the resolved config as YAML",
        "writes nothing; prints the config that --preset, --config and --set give",
    ),
    "notebooks": Stage(
        "omcrl.pipeline.notebooks:notebooks_stage",
        "run the notebook chain; executed copies in results/<preset>/executed/",
        (
            "executed/<notebook>.ipynb, executed/wall_times.json and peak_rss_mb.json, then summary.md; default: "
            "every notebook 00-09 in order (--only / --skip choose)"
        ),
        args=("only", "skip"),
    ),
    "collect": Stage(
        "omcrl.pipeline.stages:collect_stage",
        "collect trajectory data for pretraining",
        (
            "the HDF5 dataset data.file (default data/<preset>/box-seed<k>.h5); default: the box scene, the preset's "
            "episode count, the scripted pilot (data.policy)"
        ),
    ),
    "pretrain": Stage(
        "omcrl.pipeline.stages:pretrain_stage",
        "pretrain an encoder: of --method (ours, curl, curl-phi), else as cfg.pretrain says",
        (
            "runs/pretrain/<variant>-<key>/seed<k>/ (encoder.pt, run.json, metrics.csv, tb/); default: "
            "pretrain.method of the config (omc) at seed 0; a finished run of the same config is skipped"
        ),
        args=("method",),
    ),
    "oracle": Stage(
        "omcrl.pipeline.stages:oracle_stage",
        "train the privileged oracle with PPO (= train --method oracle)",
        (
            "runs/rl/oracle-<key>/seed<k>/ (final.pt, run.json, metrics.csv, tb/); default seed 0; a finished run is "
            "skipped, an interrupted one resumes"
        ),
    ),
    "student": Stage(
        "omcrl.pipeline.stages:student_stage",
        "train the oracle-guided student (= train --method ours)",
        (
            "runs/rl/ours-<key>/seed<k>/ (final.pt, run.json, metrics.csv, tb/); needs the oracle and the OMC encoder"
            " of the same seed; default seed 0"
        ),
    ),
    "train": Stage(
        "omcrl.pipeline.stages:train_stage",
        "train one method of the comparison: --method NAME [--seed K]",
        (
            "runs/rl/<method>-<key>/seed<k>/ (final.pt, run.json, metrics.csv, tb/); every missing prerequisite is "
            "named at once with its command; default seed 0"
        ),
        args=("method",),
    ),
    "evaluate": Stage(
        "omcrl.eval:evaluate_stage",
        "evaluate the policies of --seed (or cfg.seed) and write a quick table",
        (
            "eval/<method>/seed<k>/<scene>-<key>/ (cached episodes: run.json, episodes.csv) and "
            "tables/evaluate_seed<k>.{csv,md}; default: every finished policy of seed 0 and the Hybrid APF, "
            "eval.episodes per scene of eval.scenes"
        ),
    ),
    "tables": Stage(
        "omcrl.pipeline.tables:tables_stage",
        "evaluate every method at cfg.seeds and write Table I with CIs",
        (
            "tables/table1.{csv,md,tex}, table1_vs_paper.{csv,md}, table1_significance.csv, table1_episodes.csv; "
            'default: the config\'s seeds (--set "seeds=[0,1,2]" for three); missing runs are listed, not trained'
        ),
        args=("from_reference", "grid"),
    ),
    "ladder": Stage(
        "omcrl.pipeline.ladder:ladder_stage",
        "the budget ladder from the grids' records: SR by budget, the encoders' report, the ledger at each budget",
        (
            "tables/ladder_table, ladder_encoders, ladder_verdicts (.csv, .md) and figures/ladder_<scene>.png from "
            "reference/<preset>/{table1,ladder-pretrain,ladder-rl}-<suite>/; default: seeds 0-2, nothing trained or "
            "flown (--reports first writes the encoder reports the records lack, from this machine's encoders)"
        ),
        args=("reports",),
    ),
    "interpret": Stage(
        "omcrl.interpret.stage:interpret_stage",
        "disturbance tests in a simulated room, Grad-CAM mass on obstacles, feature stability (notebook 08)",
        "tables/disturbance, gradcam_mass, stability (.csv, .md) and eval/ caches; default seed 0",
    ),
    "transfer": Stage(
        "omcrl.interpret.transfer:transfer_stage",
        "why a box-trained student fails zero-shot: geometry vs look, blind student, feature shift, probe across",
        "tables/transfer_*.{csv,md}; default: seed 0's ours run and the scenes of eval.scenes",
    ),
    "gradient": Stage(
        "omcrl.interpret.gradient:gradient_stage",
        (
            "the scenes' gradient of difficulty with nothing learned: shift from box (random encoders, pixels) and "
            "planners' SR"
        ),
        "tables/scene_gradient.{csv,md}, scene_gradient_order.md; nothing trained is used",
    ),
    "sweep": Stage(
        "omcrl.pipeline.sweep:sweep_stage",
        "run a named ablation grid over seeds: sweep GRID [--seeds 0,1,2] [--backend ray|local] [--address A]",
        (
            "sweeps/<grid>/ (jobs, logs/), the runs and evaluations it makes, tables/<grid>.* ; default: the config's"
            " seeds, an embedded Ray with every core (--backend local: in this process)"
        ),
        args=(
            "grid",
            "seeds",
            "backend",
            "address",
            "num_cpus",
            "to_reference",
            "variants",
            "release",
            "plan",
            "rates",
            "rates_out",
        ),
    ),
    "summary": Stage(
        "omcrl.pipeline.summary:summary_stage",
        "write and print results/<preset>/summary.md from what the stages left",
        "summary.md (and prints it); --readme instead rewrites the README's results from reference/<preset>/",
        args=("readme",),
    ),
    "reference": Stage(
        "omcrl.pipeline.reference:reference_stage",
        (
            "unpack the trained reference runs of the preset (reference/<preset>/, verified) into results/<preset>/; "
            "--pack makes the bundle"
        ),
        (
            "unpacks reference/<preset>/bundle (or --from PATH) into runs/ and eval/, verified; --pack writes "
            "reference/<preset>/bundle from the finished Table I runs at the config's seeds"
        ),
        args=("pack", "source", "with_table", "exact", "methods", "merge", "retire"),
    ),
    "export": Stage(
        "omcrl.deploy.export:export_stage",
        "export a visuomotor policy to ONNX: --policy RUN [--out FILE]",
        "policy.onnx beside final.pt (or --out); --policy is required",
        args=("policy", "out"),
        preset=False,
    ),
    "replay": Stage(
        "omcrl.pipeline.stages:replay_stage",
        "draw a flight log (path, commands, stream ages, battery, events): LOG",
        "a PNG beside the flight log (or --out)",
        args=("log", "out"),
        preset=False,
    ),
}

# Stages that take --method; stages that need no preset (they act on a file named on the command line).
METHOD_STAGES = tuple(n for n, s in STAGES.items() if "method" in s.args)
NO_PRESET_STAGES = tuple(n for n, s in STAGES.items() if not s.preset)


class StageUnavailable(RuntimeError):
    """A registered stage whose module or function cannot be loaded (a broken install or a typo in the registry)."""


def load_stage(name: str, registry: dict[str, Stage] | None = None) -> Callable[[Config], Any]:
    """Import and return the function behind stage ``name``; raise StageUnavailable if it is not there."""
    reg = STAGES if registry is None else registry
    if name not in reg:
        raise StageUnavailable(f"unknown stage {name!r}; stages: {', '.join(reg)}")
    target = reg[name][0]
    module_name, func_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        # Only a missing stage module (or its package) means "not available"; a missing dependency
        # inside an existing module is a real error and propagates.
        if e.name and (module_name == e.name or module_name.startswith(e.name + ".")):
            raise StageUnavailable(
                f"stage {name!r} cannot be loaded ({target}: module {e.name} does not exist)"
            ) from None
        raise
    func = getattr(module, func_name, None)
    if not callable(func):
        raise StageUnavailable(f"stage {name!r} cannot be loaded ({target}: {module_name} has no function {func_name})")
    return func
