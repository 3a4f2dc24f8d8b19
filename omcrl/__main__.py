"""Command line: ``python -m omcrl <stage> --preset P [--set field=value ...] [--config FILE]``.

Every stage is a function that takes a validated :class:`omcrl.config.Config`; the CLI only builds that
config and calls it, so notebooks, tests and the CLI run the same code. Stages are imported lazily: a stage
whose module is not there yet fails with a clear message instead of breaking the whole CLI.

Examples
--------
    python -m omcrl config --preset smoke --set env.image_size=48
    python -m omcrl pretrain --preset quick --set pretrain.mask_prob=0.3
    python -m omcrl notebooks --preset smoke
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

from omcrl.config import PRESETS, ConfigError, load_config
from omcrl.pipeline.registry import METHOD_STAGES, STAGES, StageUnavailable, load_stage


def describe(result: Any) -> str:
    """What a stage returned, for a person: its own ``repr`` where it has one written for reading, else a
    dataclass's fields one per line (paths as paths, numbers rounded), not a ``Result(...)`` one-liner."""
    import dataclasses
    from pathlib import Path

    # A dataclass made with repr=False writes its own repr for reading (tables by scene, paths written).
    if not dataclasses.is_dataclass(result) or not type(result).__dataclass_params__.repr:
        return str(result)

    def short(v: Any) -> str:
        if isinstance(v, Path):
            return str(v)
        if isinstance(v, float):
            return f"{v:.4g}"
        if isinstance(v, dict):
            return ", ".join(f"{k}={short(x)}" for k, x in v.items()) or "-"
        if hasattr(v, "shape") and hasattr(v, "columns"):
            return f"table, {v.shape[0]} rows"
        text = str(v)
        return text if len(text) <= 100 else text[:97] + "..."

    fields = [(f.name, getattr(result, f.name)) for f in dataclasses.fields(result)]
    return "\n".join(f"{name}: {short(v)}" for name, v in fields)


def _methods_help(stage: str = "train") -> str:
    """The methods ``stage`` takes: every learned one for ``train``, those with a pretrained encoder for
    ``pretrain``."""
    from omcrl.rl.methods import METHODS

    keep = (lambda s: s.recipe.pretrained) if stage == "pretrain" else (lambda s: s.learned)
    return "\n".join(f"  {n:<22} {s.description}" for n, s in METHODS.items() if keep(s))


PRESET_HELP = (
    "configuration preset, required: smoke (minutes; checks the plumbing, numbers mean nothing), quick (a laptop "
    "CPU, hours), paper (the paper's scale, a GPU machine)"
)


def _stage_epilog(name: str) -> str:
    import textwrap

    out = "writes and defaults:\n" + textwrap.fill(STAGES[name].outputs, 100, initial_indent="  ",
                                                    subsequent_indent="  ")  # fmt: skip
    if name in METHOD_STAGES:
        out += f"\n\nmethods (--method):\n{_methods_help(name)}"
    return out


def build_parser() -> argparse.ArgumentParser:
    """The CLI: one sub-command per stage, each with its own ``--help``."""
    ap = argparse.ArgumentParser(
        prog="python -m omcrl",
        description="Run one stage of the OMC-RL reproduction kit. `python -m omcrl <stage> --help` for a stage.",
        epilog=f"methods (--method):\n{_methods_help()}\n\nexamples:\n"
        "  python -m omcrl pretrain --method curl --preset quick\n"
        "  python -m omcrl train --method curl --preset quick --seed 1\n"
        "  python -m omcrl tables --preset quick --set seeds=[0,1,2]\n"
        "  python -m omcrl summary --preset quick",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = ap.add_subparsers(dest="stage", metavar="stage", title="stages")
    for name, stage in STAGES.items():
        desc = stage.description
        sp = sub.add_parser(
            name,
            help=desc,
            description=f"python -m omcrl {name}: {desc}.",
            epilog=_stage_epilog(name),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        if not stage.preset:
            sp.add_argument("--preset", default="smoke", choices=PRESETS, help=argparse.SUPPRESS)
        else:
            sp.add_argument("--preset", required=True, choices=PRESETS, help=PRESET_HELP)
        sp.add_argument(
            "--set",
            dest="overrides",
            action="append",
            default=[],
            metavar="FIELD=VALUE",
            help="override one config field, e.g. --set env.image_size=48 (repeatable)",
        )
        sp.add_argument(
            "--config",
            metavar="FILE",
            default=None,
            help="YAML file applied after the preset and before --set (e.g. a run's config.yaml)",
        )
        sp.add_argument("--seed", type=int, default=None, help="training seed (sets the config field 'seed')")
        sp.add_argument("--debug", action="store_true", help="show the full traceback of an error")
        # --method is accepted everywhere so that a misplaced one gets a message naming the stages it fits.
        sp.add_argument(
            "--method",
            default=None,
            help="method of the comparison (see below)" if name in METHOD_STAGES else argparse.SUPPRESS,
        )
        if name == "sweep":
            from omcrl.pipeline.grids import GRIDS

            sp.add_argument(
                "grid",
                nargs="?",
                default=None,
                help=f"the grid to run: one of {list(GRIDS)}, or all (the six ablations)",
            )
            sp.add_argument(
                "--seeds", type=_seeds, default=None, help="comma-separated seeds (default: the config's seeds)"
            )
            sp.add_argument("--backend", default="ray", choices=("ray", "local"), help="Ray tasks or in-process")
            sp.add_argument("--address", default=None, help="a Ray cluster (auto, ray://host:port); default: embedded")
            sp.add_argument("--num-cpus", type=int, default=None, help="CPUs of an embedded Ray (default: cores)")
            sp.add_argument("--plan", action="store_true", help="print the jobs and their estimated cost; run nothing")
            sp.add_argument(
                "--to-reference",
                action="store_true",
                help="keep each finished run's records and episodes in reference/<preset>/<grid>-<suite>/ (commit "
                "them) and train only what is not kept there yet",
            )
            sp.add_argument("--rates", default=None, help="with --plan: JSON {rate_key: units/s} (default: measured)")
            sp.add_argument(
                "--rates-out",
                default=None,
                metavar="FILE.json",
                help="with --plan: also write the rates it used, in --rates' format, to a new file (kept beside a "
                "grid's data, it is what the grid's measured cost is set against)",
            )
            sp.add_argument(
                "--release-teachers",
                dest="release",
                action="store_true",
                help="only take the committed weights of teachers whose students are all recorded out of "
                "reference/ (they are then read from git history); run nothing",
            )
            sp.add_argument(
                "--variants",
                type=_csv,
                default=None,
                metavar="LABEL,..",
                help="only these variants of the grid (and what they need), e.g. ours-lapf,curl",
            )
        if name == "notebooks":
            sp.add_argument("--only", type=_csv, metavar="NN,..", help="run only these notebooks, e.g. 05,07")
            sp.add_argument("--skip", type=_csv, metavar="NN,..", help="leave these out, e.g. 06 (the ablations)")
        if name == "summary":
            sp.add_argument(
                "--readme",
                action="store_true",
                help="instead: rewrite the README's 'Results at a glance' from reference/<preset>/table1/",
            )
        if name == "reference":
            sp.add_argument(
                "--from",
                dest="source",
                default=None,
                metavar="PATH",
                help="a bundle folder (default: reference/<preset> in the checkout); with --pack, where to write it",
            )
            sp.add_argument(
                "--pack",
                action="store_true",
                help="make the bundle from results/<preset>/ (the Table I runs at the config's seeds) instead",
            )
            sp.add_argument(
                "--exact",
                action="store_true",
                help="with --pack: keep every bit of the weights (default: weight matrices rounded to float16 "
                "precision, the effect on Table I's episodes measured and recorded)",
            )
            sp.add_argument(
                "--with-table",
                action="store_true",
                help="with --pack: make results/<preset>/tables/ the reference Table I (reference/<preset>/table1/)",
            )
            sp.add_argument(
                "--methods",
                type=_csv,
                default=None,
                help="with --pack: only these learned methods (comma-separated) and the runs they were trained "
                "from: a part of a bundle, merged later with --merge",
            )
            sp.add_argument(
                "--merge",
                default=None,
                metavar="DIR",
                help="instead: merge every bundle folder in DIR (parts packed with --methods) into one bundle at "
                "--from (default reference/<preset>/bundle)",
            )
            sp.add_argument(
                "--retire",
                action="store_true",
                help="instead: move the committed bundle at --from out of the checkout into git history (a pointer "
                "stays; it still verifies and unpacks from a full clone)",
            )
        if name == "tables":
            sp.add_argument(
                "--from-reference",
                action="store_true",
                help="rebuild Table I, the ledger's verdicts and Fig. 5 from reference/<preset>/table1-<suite>/ "
                "alone (nothing trained or flown)",
            )
            sp.add_argument(
                "--grid",
                default="table1",
                help="with --from-reference: the grid of Table I's runs to read (table1-confirm: the same runs in "
                "200 layouts Table I never flew; its tables go to results/<preset>/tables/table1-confirm/), or "
                "ablations: Tables II-III, Figs. 7-10 and the six findings from the ablation grids' data",
            )
        if name == "ladder":
            sp.add_argument(
                "--reports",
                action="store_true",
                help="first write the encoder reports (probe R², shift, top-1) the grids' records lack, from the "
                "encoders in results/<preset>/runs/pretrain (pilot frames flown once)",
            )
        if name == "replay":
            sp.add_argument("log", help="a flight log CSV (ControlLoop's log_path)")
            sp.add_argument("--out", default=None, help="the PNG (default: beside the log)")
        if name == "export":
            sp.add_argument("--policy", default=None, help="a run folder or its final.pt (required)")
            sp.add_argument("--out", default=None, help="the ONNX file (default: policy.onnx beside final.pt)")
    return ap


def _csv(text: str) -> list[str]:
    """``"05,07"`` -> ``["05", "07"]`` (an argument's ``type``: an absent argument keeps its default, None)."""
    return [t.strip() for t in text.split(",") if t.strip()]


def _seeds(text: str) -> list[int]:
    """``"0,1,2"`` -> ``[0, 1, 2]``."""
    try:
        return [int(t) for t in _csv(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _expected_errors() -> tuple[type[BaseException], ...]:
    """Errors whose message says all a user needs: printed as one line, exit code 1."""
    # Imported when a stage runs, not with the CLI: they pull in PyTorch (1.2 s), which `--help` and a wrong
    # argument should not wait for.
    from omcrl.data.dataset import DatasetError
    from omcrl.deploy.export import ExportError
    from omcrl.deploy.runtime import ModelSpecError
    from omcrl.models.artifact import EncoderError
    from omcrl.models.features import CheckpointError
    from omcrl.pipeline.glance import GlanceError
    from omcrl.pipeline.notebooks import NotebookError
    from omcrl.pipeline.reference import ReferenceError
    from omcrl.pipeline.sweep import ClusterError, SweepFailed
    from omcrl.rl.ppo import NonFiniteLossError
    from omcrl.runs import CorruptFile, RunConfigMismatch, RunLocked
    from omcrl.utils.io import UnsafeFileError

    return (
        CheckpointError,
        RunConfigMismatch,
        RunLocked,
        CorruptFile,
        FileNotFoundError,
        NotADirectoryError,
        ExportError,
        DatasetError,
        EncoderError,
        ModelSpecError,
        UnsafeFileError,
        NotebookError,
        ReferenceError,
        GlanceError,
        NonFiniteLossError,
        SweepFailed,
        ClusterError,
    )


# What a user who pressed Ctrl-C needs to know: nothing finished is lost, and the same command goes on.
INTERRUPTED = (
    "what finished is kept (trained runs, their last checkpoint, cached evaluations, executed notebooks); "
    "run the same command again to resume"
)


def _parse(argv: list[str]) -> tuple[argparse.Namespace, Any, Any] | int:
    """The arguments, the validated config and the stage's function; or an exit code, the error printed (2: usage
    or config, 3: the stage's module cannot be loaded), before any work."""
    ap = build_parser()
    first = next((a for a in argv if not a.startswith("-")), None)
    if first is not None and first not in STAGES:
        ap.print_usage(sys.stderr)
        print(f"error: unknown stage {first!r}; stages: {', '.join(STAGES)}", file=sys.stderr)
        return 2
    args = ap.parse_args(argv)
    if args.stage is None:
        ap.print_help(sys.stderr)
        return 2
    if args.method is not None and args.stage not in METHOD_STAGES:
        print(f"error: --method applies to the stages {list(METHOD_STAGES)}, not {args.stage!r}", file=sys.stderr)
        return 2
    overrides = list(args.overrides) + ([f"seed={args.seed}"] if args.seed is not None else [])
    try:
        cfg = load_config(args.preset, overrides=overrides, path=args.config)
        if args.method is not None:
            from omcrl.rl.methods import get_method

            get_method(args.method)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        return args, cfg, load_stage(args.stage)
    except StageUnavailable as e:
        print(f"error: {e}", file=sys.stderr)
        return 3


def _failed(e: BaseException, args: argparse.Namespace) -> int:
    """The exit code of a stage that raised ``e``, with one line for the user (130: Ctrl-C, 2: a config error, 1:
    an expected failure); anything else, and every error under ``--debug``, is raised with its traceback."""
    if isinstance(e, KeyboardInterrupt):
        print(f"\ninterrupted: stage {args.stage}; {INTERRUPTED}", file=sys.stderr)
        return 130
    if args.debug or not isinstance(e, (ConfigError, *_expected_errors())):
        raise e
    # Expected failures (a prerequisite missing, a corrupt or foreign file, a run of another configuration): one
    # line naming the file and the problem.
    text = str(e) if isinstance(e, ConfigError) else (str(e).splitlines()[0] if str(e) else type(e).__name__)
    print(f"error: {text}", file=sys.stderr)
    return 2 if isinstance(e, ConfigError) else 1


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m omcrl <stage> ...``: the stage's config built and checked, the stage called, the exit code."""
    parsed = _parse(list(sys.argv[1:] if argv is None else argv))
    if isinstance(parsed, int):
        return parsed
    args, cfg, stage = parsed
    t0 = time.perf_counter()
    try:
        result = stage(cfg, **{name: getattr(args, name) for name in STAGES[args.stage].args})
    except BaseException as e:  # _failed raises again what it does not report
        return _failed(e, args)
    if args.stage not in ("config", "summary"):
        if result is not None:
            print(describe(result))
        print(f"[omcrl] stage {args.stage} (preset {cfg.preset}) finished in {time.perf_counter() - t0:.1f} s",
              file=sys.stderr)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
