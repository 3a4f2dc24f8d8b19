"""The CLI's stage table: ``name -> "module:function"`` with a one-line description, and :func:`load_stage`.

Every stage takes the resolved :class:`~omcrl.config.Config` first, so notebooks, tests, sweeps and the CLI run
the same code. A stage's module is imported when the stage runs, not with this table, so ``--help`` and a
stage's first line do not wait for PyTorch and PyBullet to load.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from omcrl.config import Config

# name -> (target "module:function", one-line description)
STAGES: dict[str, tuple[str, str]] = {
    "config": ("omcrl.pipeline.stages:print_config", "print the resolved config as YAML"),
    "notebooks": (
        "omcrl.pipeline.notebooks:notebooks_stage",
        "run the notebook chain; executed copies in results/<preset>/executed/",
    ),
    "collect": ("omcrl.pipeline.stages:collect_stage", "collect trajectory data for pretraining"),
    "pretrain": (
        "omcrl.pipeline.stages:pretrain_stage",
        "pretrain an encoder: of --method (ours, curl, curl-phi), else as cfg.pretrain says",
    ),
    "oracle": ("omcrl.pipeline.stages:oracle_stage", "train the privileged oracle with PPO (= train --method oracle)"),
    "student": ("omcrl.pipeline.stages:student_stage", "train the oracle-guided student (= train --method ours)"),
    "train": ("omcrl.pipeline.stages:train_stage", "train one method of the comparison: --method NAME [--seed K]"),
    "evaluate": ("omcrl.eval:evaluate_stage", "evaluate the policies of --seed (or cfg.seed) and write a quick table"),
    "tables": ("omcrl.eval.table1:tables_stage", "evaluate every method at cfg.seeds and write Table I with CIs"),
    "interpret": (
        "omcrl.interpret.stage:interpret_stage",
        "disturbance tests in a simulated room, Grad-CAM mass on obstacles, feature stability (notebook 08)",
    ),
    "transfer": (
        "omcrl.interpret.transfer:transfer_stage",
        "why a box-trained student fails zero-shot: geometry vs look, blind student, feature shift, probe across",
    ),
    "gradient": (
        "omcrl.interpret.gradient:gradient_stage",
        "the scenes' gradient of difficulty with nothing learned: shift from box (random encoders, pixels) and "
        "planners' SR",
    ),
    "sweep": (
        "omcrl.pipeline.sweep:sweep_stage",
        "run a named ablation grid over seeds: sweep GRID [--seeds 0,1,2] [--backend ray|local] [--address A]",
    ),
    "summary": (
        "omcrl.pipeline.summary:summary_stage",
        "write and print results/<preset>/summary.md from what the stages left",
    ),
    "export": ("omcrl.deploy.export:export_stage", "export a visuomotor policy to ONNX: --policy RUN [--out FILE]"),
    "replay": (
        "omcrl.pipeline.stages:replay_stage",
        "draw a flight log (path, commands, stream ages, battery, events): LOG",
    ),
}
# Stages that take --method.
METHOD_STAGES = ("train", "pretrain")


class StageUnavailable(RuntimeError):
    """A registered stage whose module or function cannot be loaded (a broken install or a typo in the registry)."""


def load_stage(name: str, registry: dict[str, tuple[str, str]] | None = None) -> Callable[[Config], Any]:
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


# Stages that need no preset (they act on a file named on the command line).
NO_PRESET_STAGES = ("export", "replay")
