"""Run the numbered notebooks headless with papermill, one preset at a time.

The notebooks in ``notebooks/NN_*.ipynb`` are committed without outputs. Each has exactly one cell tagged
``parameters`` that assigns at least ``preset``; it may also assign ``results_dir`` (a config field) and
``overrides`` (a list of ``"section.field=value"`` strings for :func:`omcrl.config.load_config`). The runner
injects ``preset`` and, when the notebook declares them, ``results_dir`` and ``overrides``; any further
``parameters`` are injected as given.

The executed copy, with outputs, goes to ``<results_dir>/<preset>/executed/<name>.ipynb``. The kernel is the
interpreter running this code (see :func:`resolve_kernel`), so the notebooks see the same installed ``omcrl``.

Example
-------
>>> from omcrl.pipeline.notebooks import NOTEBOOKS, run_chain
>>> run_chain("smoke")                      # doctest: +SKIP
"""

from __future__ import annotations

import ast
import atexit
import contextlib
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

from omcrl.config import PRESETS, ConfigError, overrides_from_config, resolve_path
from omcrl.pipeline.expected import chain_plan, grid_evaluation_seconds, grid_training_seconds, notebook_estimate
from omcrl.scenes import suite_of
from omcrl.utils.io import atomic_write_text
from omcrl.utils.memory import PeakRSS
from omcrl.utils.progress import STATUS_FILE_ENV, format_duration

REPO_ROOT = Path(__file__).resolve().parents[2]
NOTEBOOK_DIR = REPO_ROOT / "notebooks"
NATIVE_KERNEL = "python3"
PRIVATE_KERNEL = "omcrl-python"
# Parameters the runner fills in only when the notebook's parameters cell declares them.
OPTIONAL_PARAMETERS = ("results_dir", "overrides")

log = logging.getLogger(__name__)


class NotebookError(RuntimeError):
    """A notebook could not be found, is malformed, or failed while executing."""


class NotebookNotFoundError(NotebookError, FileNotFoundError):
    """The named notebook does not exist."""


class NotebookExecutionError(NotebookError):
    """A cell raised while the notebook ran; the message names the notebook, the cell and the error."""

    def __init__(self, message: str, *, notebook: str, cell: int | None, executed: Path) -> None:
        super().__init__(message)
        self.notebook = notebook
        self.cell = cell
        self.executed = executed


# ---------------------------------------------------------------- discovery
def discover_notebooks(directory: str | Path | None = None) -> list[str]:
    """Names (file stems) of ``NN_*.ipynb`` in ``directory`` (default ``notebooks/``), in numeric order."""
    d = Path(directory) if directory is not None else NOTEBOOK_DIR
    if not d.is_dir():
        return []
    names = [p.stem for p in d.glob("[0-9][0-9]_*.ipynb") if p.is_file()]
    return sorted(names)


NOTEBOOKS: list[str] = discover_notebooks()


def notebook_path(name_or_path: str | Path) -> Path:
    """Resolve a notebook name (``"03_train_oracle"``), its number prefix (``"03"``) or a path to a file."""
    text = str(name_or_path)
    p = Path(text)
    if p.suffix == ".ipynb" or p.parent != Path("."):
        if not p.is_file():
            raise NotebookNotFoundError(f"notebook {text!r} does not exist")
        return p
    names = discover_notebooks()
    # A number prefix may be written without its zero: 7 is 07.
    number = (lambda t: str(int(t))) if text.isdigit() else (lambda t: t)
    matches = [n for n in names if n == text] or [
        n for n in names if n.split("_", 1)[0].isdigit() and number(n.split("_", 1)[0]) == number(text)
    ]
    if len(matches) != 1:
        listed = ", ".join(names) if names else "none"
        why = "is ambiguous" if matches else "was not found"
        raise NotebookNotFoundError(f"notebook {text!r} {why} in {NOTEBOOK_DIR}; available: {listed}")
    return NOTEBOOK_DIR / f"{matches[0]}.ipynb"


# ---------------------------------------------------------------- notebook hygiene
def parameters_cells(nb: Any) -> list[int]:
    """Indices of the cells tagged ``parameters``."""
    return [i for i, c in enumerate(nb.cells) if "parameters" in c.get("metadata", {}).get("tags", [])]


def declared_parameters(nb: Any) -> list[str]:
    """Names assigned in the notebook's ``parameters`` cell(s), in order."""
    names: list[str] = []
    for i in parameters_cells(nb):
        try:
            tree = ast.parse(nb.cells[i].source)
        except SyntaxError as e:
            raise NotebookError(f"parameters cell {i} does not parse: {e}") from None
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
            for t in targets:
                if isinstance(t, ast.Name) and t.id not in names:
                    names.append(t.id)
    return names


def check_notebook(path: str | Path) -> list[str]:
    """Problems that keep a notebook from being committed as is; an empty list means it is clean.

    Rules: no outputs and no execution counts in any code cell, and exactly one cell tagged ``parameters``
    that assigns ``preset``.
    """
    import nbformat

    nb = nbformat.read(str(path), as_version=4)
    problems = []
    for i, c in enumerate(nb.cells):
        if c.cell_type == "code" and (c.get("outputs") or c.get("execution_count") is not None):
            problems.append(
                f"cell {i} has outputs or an execution count (run: python -m omcrl.pipeline.notebooks strip {path})"
            )
    cells = parameters_cells(nb)
    if len(cells) != 1:
        problems.append(f"expected exactly one cell tagged 'parameters', found {len(cells)}")
    elif "preset" not in declared_parameters(nb):
        problems.append(f"the parameters cell (cell {cells[0]}) does not assign 'preset'")
    return problems


def strip_outputs(path: str | Path) -> bool:
    """Clear outputs, execution counts and run metadata of a notebook in place; True if it changed."""
    import nbformat

    p = Path(path)
    before = p.read_text(encoding="utf-8")
    nb = nbformat.reads(before, as_version=4)
    for c in nb.cells:
        if c.cell_type == "code":
            c.outputs = []
            c.execution_count = None
        for key in ("execution", "papermill", "collapsed", "scrolled"):
            c.metadata.pop(key, None)
    for key in ("papermill", "widgets"):
        nb.metadata.pop(key, None)
    after = nbformat.writes(nb)
    if not after.endswith("\n"):
        after += "\n"  # as nbformat.write does
    if after == before:
        return False
    atomic_write_text(p, after)
    return True


# ---------------------------------------------------------------- kernel
def _is_current_python(argv0: str) -> bool:
    """Would jupyter_client start ``argv0`` as this very interpreter?"""
    major, minor = sys.version_info[:2]
    if argv0 in ("python", f"python{major}", f"python{major}.{minor}"):
        return True  # jupyter_client replaces these bare names by sys.executable
    found = shutil.which(argv0) or argv0
    # Compare folders, not resolved symlinks: every venv's python links to the same base interpreter.
    here = Path(os.path.abspath(sys.executable))
    there = Path(os.path.abspath(found))
    return there.parent == here.parent and there.name.startswith("python")


@lru_cache(maxsize=1)
def resolve_kernel() -> tuple[str, str | None]:
    """Return ``(kernel_name, extra_jupyter_path)`` for a kernel that runs ``sys.executable``.

    The venv's ipykernel installs a ``python3`` kernelspec whose command is the bare word ``python``, which
    jupyter_client replaces by ``sys.executable``; that spec is used when it is the one found. If another
    ``python3`` spec shadows it (for example a user-level one pointing at a different interpreter) or there
    is none, a private spec ``omcrl-python`` naming ``sys.executable`` is written to a temporary folder that
    is put first on ``JUPYTER_PATH`` while notebooks run; nothing is installed in the user's Jupyter.
    """
    from jupyter_client.kernelspec import KernelSpecManager, NoSuchKernel

    try:
        spec = KernelSpecManager().get_kernel_spec(NATIVE_KERNEL)
        if spec.argv and _is_current_python(spec.argv[0]):
            return NATIVE_KERNEL, None
        log.info(
            "kernelspec %s runs %s, not %s; using a private kernelspec",
            NATIVE_KERNEL,
            spec.argv[0],
            sys.executable,
        )
    except NoSuchKernel:
        log.info("no %s kernelspec; using a private kernelspec", NATIVE_KERNEL)
    root = Path(tempfile.mkdtemp(prefix="omcrl-jupyter-"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    kdir = root / "kernels" / PRIVATE_KERNEL
    kdir.mkdir(parents=True)
    spec = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": f"Python {sys.version_info[0]}.{sys.version_info[1]} (omcrl)",
        "language": "python",
        "metadata": {"debugger": False},
    }
    (kdir / "kernel.json").write_text(json.dumps(spec, indent=1))
    return PRIVATE_KERNEL, str(root)


@contextlib.contextmanager
def _kernel_environment(extra_jupyter_path: str | None) -> Iterator[None]:
    """Environment the kernel inherits: private kernelspec path, inline plots, bounded threads."""
    saved = dict(os.environ)
    try:
        if extra_jupyter_path:
            old = os.environ.get("JUPYTER_PATH")
            os.environ["JUPYTER_PATH"] = os.pathsep.join(p for p in (extra_jupyter_path, old) if p)
        # reproduce.sh exports MPLBACKEND=Agg for scripts; inside a kernel the inline backend (also headless)
        # keeps figures in the executed notebook, and ipykernel only picks it when MPLBACKEND is unset.
        if os.environ.get("MPLBACKEND", "").lower() == "agg":
            del os.environ["MPLBACKEND"]
        os.environ.setdefault("OMP_NUM_THREADS", str(min(2, os.cpu_count() or 1)))
        os.environ.setdefault("PYDEVD_DISABLE_FILE_VALIDATION", "1")
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)


# ---------------------------------------------------------------- running
def _error_message(name: str, nb_source: Any, err: Any, executed: Path) -> tuple[str, int | None]:
    """Name the notebook, the failing cell (1-based, as in the committed notebook) and the error."""
    cell_no = None
    for i, c in enumerate(nb_source.cells):
        if c.cell_type == "code" and c.source == err.source:
            cell_no = i + 1
            break
    where = f"cell {cell_no} of {len(nb_source.cells)}" if cell_no else f"cell index {err.cell_index}"
    first = next((ln for ln in str(err.source).splitlines() if ln.strip()), "")
    msg = (
        f"notebook {name} failed in {where} (In [{err.exec_count}]: {first.strip()[:80]!r}): "
        f"{err.ename}: {err.evalue}\nexecuted copy with the traceback: {executed}"
    )
    return msg, cell_no


def run_notebook(
    name_or_path: str | Path,
    preset: str,
    parameters: dict | None = None,
    results_dir: str | Path = "results",
    *,
    overrides: Sequence[str] = (),
    cwd: str | Path | None = None,
    timeout: float | None = None,
) -> Path:
    """Execute one notebook with papermill and return the path of its executed copy.

    Parameters
    ----------
    name_or_path : ``"03_train_oracle"``, ``"03"`` or a path to an ``.ipynb``.
    preset : ``smoke``, ``quick`` or ``paper``; injected as ``preset``.
    parameters : more values to inject (names must be assigned in the notebook's parameters cell).
    results_dir : root of the outputs; the executed copy goes to ``<results_dir>/<preset>/executed/``. A
        relative path is taken from ``cwd``. Injected as ``results_dir`` when the notebook declares it.
    overrides : ``"section.field=value"`` strings, injected as ``overrides`` when the notebook declares it.
    cwd : working directory of the kernel (default: the repository root).
    timeout : per-cell limit in seconds (default: none).
    """
    import nbformat
    import papermill as pm
    from papermill.exceptions import PapermillExecutionError

    if preset not in PRESETS:
        raise ConfigError(f"preset: got {preset!r}, allowed values are {list(PRESETS)}")
    src = notebook_path(name_or_path)
    name = src.stem
    workdir = Path(cwd) if cwd is not None else REPO_ROOT
    root = Path(results_dir)
    if not root.is_absolute():
        root = workdir / root if cwd is not None else resolve_path(root)
    out = root / preset / "executed" / f"{name}.ipynb"
    out.parent.mkdir(parents=True, exist_ok=True)

    nb = nbformat.read(str(src), as_version=4)
    if len(parameters_cells(nb)) != 1:
        raise NotebookError(f"notebook {name} must have exactly one cell tagged 'parameters'")
    declared = declared_parameters(nb)
    params: dict[str, Any] = {"preset": preset}
    optional = {"results_dir": str(root), "overrides": list(overrides)}
    for key in OPTIONAL_PARAMETERS:
        if key in declared:
            params[key] = optional[key]
    if "results_dir" not in declared and Path(results_dir) != Path("results"):
        log.warning("notebook %s does not declare 'results_dir'; it writes to its default", name)
    if overrides and "overrides" not in declared:
        raise NotebookError(
            f"notebook {name} does not declare 'overrides' in its parameters cell, so the "
            f"overrides {list(overrides)} cannot reach it"
        )
    params.update(parameters or {})

    kernel, extra_path = resolve_kernel()
    with _kernel_environment(extra_path):
        try:
            pm.execute_notebook(
                str(src),
                str(out),
                parameters=params,
                kernel_name=kernel,
                language="python",
                cwd=str(workdir),
                progress_bar=False,
                execution_timeout=timeout,
                # The kernel's own log is noise on the console of a headless run: its start-up warnings ("running
                # over TCP without encryption", how every local kernel runs), and on Ctrl-C a 20-line ZMQ traceback
                # of a reply to a client that has gone. A cell's error reaches us as PapermillExecutionError and a
                # dead kernel as the exception below, so nothing a user needs is in it.
                extra_arguments=["--IPKernelApp.log_level=CRITICAL"],
            )
        except PapermillExecutionError as err:
            msg, cell = _error_message(name, nb, err, out)
            raise NotebookExecutionError(msg, notebook=name, cell=cell, executed=out) from None
        except Exception as err:  # kernel died, timeout, bad parameters ...
            raise NotebookExecutionError(
                f"notebook {name} could not run: {type(err).__name__}: {err}\nexecuted copy (may be partial): {out}",
                notebook=name,
                cell=None,
                executed=out,
            ) from err
    return out


def run_chain(
    preset: str,
    names: Sequence[str] | None = None,
    parameters: dict | None = None,
    results_dir: str | Path = "results",
    *,
    overrides: Sequence[str] = (),
    cwd: str | Path | None = None,
    verbose: bool = True,
    rl_steps: int | None = None,
    train_s: dict[str, float] | None = None,
    eval_s: dict[str, float] | None = None,
    suite: str | None = None,
) -> list[Path]:
    """Run ``names`` (default: all of :data:`NOTEBOOKS`) in the given order; stop at the first failure.

    Later notebooks read artifacts written by earlier ones, so the default order is the numeric one. First it prints
    its plan (``verbose``): each notebook with its estimate and the total (:func:`~omcrl.pipeline.expected.chain_plan`;
    ``rl_steps``: the runs' env steps; ``train_s`` and ``eval_s``: measured training seconds per method at that
    budget and evaluation seconds per method; ``suite``: the scene suite in use).
    """
    chain = list(names) if names is not None else discover_notebooks()
    if not chain:
        raise NotebookNotFoundError(f"no notebooks NN_*.ipynb in {NOTEBOOK_DIR}")
    if verbose:
        for line in chain_plan(preset, chain, rl_steps, train_s, eval_s, suite):
            print(f"[notebooks] {line}", flush=True)
    done = []
    for n in chain:
        t0 = time.perf_counter()
        if verbose:
            want, _ = notebook_estimate(preset, n, suite, rl_steps, train_s, eval_s)  # as the plan above
            hint = f", about {format_duration(want)} from nothing trained on 2 cores" if want else ""
            print(f"[notebooks] {n} (preset {preset}{hint}) ...", flush=True)
        # Peak memory of the kernel and the workers it starts, every 0.25 s (an upper bound: see PeakRSS).
        with _console_feed(n if verbose else None), PeakRSS(0.25, children=True) as mem:
            out = run_notebook(n, preset, parameters=parameters, results_dir=results_dir, overrides=overrides, cwd=cwd)
        wall = time.perf_counter() - t0
        _record_wall_time(out.parent, n, wall)
        _record(out.parent / "peak_rss_mb.json", n, round(mem.peak_mb))
        if verbose:
            print(f"[notebooks] {n} done in {format_duration(wall)}, peak {mem.peak_mb:,.0f} MB -> {out}", flush=True)
        done.append(out)
    return done


@contextlib.contextmanager
def _console_feed(name: str | None, poll_s: float = 1.0) -> Iterator[None]:
    """While a notebook runs, print the status lines its loops append to ``OMCRL_STATUS_FILE`` on the console.

    The kernel's output goes into the executed notebook, not to the terminal; this feed is what keeps a long
    headless run from looking hung. ``name=None``: no feed.
    """
    if name is None:
        yield
        return
    import threading

    fd, path = tempfile.mkstemp(prefix="omcrl-status-", suffix=".log")
    os.close(fd)
    stop = threading.Event()

    def pump() -> None:
        with open(path, encoding="utf-8") as fh:
            while True:
                line = fh.readline()
                if line:
                    print(f"[notebooks] {name} | {line.rstrip()}", flush=True)
                    continue
                if stop.is_set():
                    return
                stop.wait(poll_s)

    saved = os.environ.get(STATUS_FILE_ENV)
    os.environ[STATUS_FILE_ENV] = path
    thread = threading.Thread(target=pump, name="omcrl-status", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=5)
        if saved is None:
            os.environ.pop(STATUS_FILE_ENV, None)
        else:
            os.environ[STATUS_FILE_ENV] = saved
        with contextlib.suppress(OSError):
            os.unlink(path)


def _record_wall_time(executed_dir: Path, name: str, wall_s: float) -> None:
    """Keep each notebook's last wall time in ``executed/wall_times.json`` (read by the summary)."""
    _record(executed_dir / "wall_times.json", name, round(wall_s, 1))


def _record(path: Path, name: str, value: float) -> None:
    """Set ``name`` to ``value`` in the JSON object at ``path`` (atomically; an unreadable file starts anew)."""
    try:
        d = json.loads(path.read_text()) if path.exists() else {}
    except (OSError, ValueError):
        d = {}
    d[name] = value
    atomic_write_text(path, json.dumps(dict(sorted(d.items())), indent=1) + "\n")


def select_notebooks(only: Sequence[str] | None = None, skip: Sequence[str] | None = None) -> list[str]:
    """The chain in numeric order, restricted to ``only`` and without ``skip`` (names or number prefixes).

    Every entry must name exactly one notebook, so a typo fails here, before anything runs.

    Examples
    --------
    >>> select_notebooks(skip=["06"])[:2]  # doctest: +SKIP
    ['00_scenes', '01_collect_data']
    """
    names = discover_notebooks()

    def resolve(items: Sequence[str], flag: str) -> set[str]:
        out = set()
        for it in items:
            try:
                out.add(notebook_path(it).stem)
            except NotebookNotFoundError as e:
                raise NotebookNotFoundError(f"{flag} {it}: {e}") from None
        return out

    keep = resolve(only, "--only") if only else set(names)
    drop = resolve(skip, "--skip") if skip else set()
    chain = [n for n in names if n in keep and n not in drop]
    if not chain:
        raise NotebookNotFoundError(f"--only {list(only or [])} --skip {list(skip or [])} leaves no notebook to run")
    return chain


def check_choice(argv: Sequence[str]) -> int:
    """Exit status for the ``--only`` / ``--skip`` of a command line (``reproduce.sh``'s, checked before any work):
    0 when every entry names one notebook, else 2 with the error on stderr."""
    import argparse
    import sys

    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("--only", default=None)
    ap.add_argument("--skip", default=None)
    args, _ = ap.parse_known_args(list(argv))
    items = {k: [t.strip() for t in v.split(",") if t.strip()] for k, v in vars(args).items() if v is not None}
    try:
        select_notebooks(items.get("only"), items.get("skip"))
    except NotebookNotFoundError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def notebooks_stage(cfg: Any, only: Sequence[str] | None = None, skip: Sequence[str] | None = None) -> None:
    """CLI stage ``notebooks``: run the chain for ``cfg.preset`` (all notebooks, or ``only`` / without ``skip``),
    passing on every non-default field, then write and print the summary (:mod:`omcrl.pipeline.summary`)."""
    chain = select_notebooks(only, skip)
    overrides = [o for o in overrides_from_config(cfg) if not o.startswith("results_dir=")]
    suite = suite_of(cfg.env.scene)
    run_chain(
        cfg.preset,
        names=chain,
        results_dir=cfg.results_root,
        overrides=overrides,
        rl_steps=cfg.rl.total_steps,
        train_s=grid_training_seconds(cfg.preset, suite, cfg.rl.total_steps),
        eval_s=grid_evaluation_seconds(cfg.preset, suite),
        suite=suite,
    )
    # Imported here: the summary pulls in torch and the evaluation stack (8.4 s of imports under two training runs,
    # against 0.36 s without), and reproduce.sh imports this module to check --only / --skip before any work.
    from omcrl.pipeline.summary import write_summary

    path = write_summary(cfg)
    print(path.read_text(encoding="utf-8"))
    print(f"[notebooks] summary: {path}", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m omcrl.pipeline.notebooks strip|check|list [FILES]``: clean, check or list the notebooks."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m omcrl.pipeline.notebooks", description=main.__doc__)
    ap.add_argument("action", choices=("strip", "check", "list"))
    ap.add_argument("files", nargs="*", help="default: every notebooks/NN_*.ipynb")
    a = ap.parse_args(argv)
    files = [Path(f) for f in a.files] or [NOTEBOOK_DIR / f"{n}.ipynb" for n in discover_notebooks()]
    status = 0
    for f in files:
        if a.action == "list":
            print(f.stem)
        elif a.action == "strip":
            print(f"{f}: {'stripped' if strip_outputs(f) else 'clean'}")
        else:
            problems = check_notebook(f)
            for p in problems:
                print(f"{f}: {p}")
            status |= bool(problems)
    return status


if __name__ == "__main__":
    sys.exit(main())
