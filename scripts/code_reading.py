"""What a reader meets on the way to the method: measured, for before/after figures of restructurings (issue 76).

    python scripts/code_reading.py [--json OUT]

Runs the smoke preset's chain in a temporary results folder (collect, pretrain ``omc``, the oracle, then ``ours``)
through the CLI's ``main`` and, with the profiler, measures:

* ``path/pretrain`` and ``path/train``: the call stack at the first ``optimizer.step()`` of ``python -m omcrl
  pretrain`` and of ``python -m omcrl train --method ours`` (its oracle and encoder already made): the omcrl frames
  from the CLI down, their files, and the lines of the functions those frames run (each function's whole source,
  counted once), which is what a reader reads to get from the command to the gradient step;
* ``cfg``: the stops of the config on the way, from ``pipeline/recipes.py:train_method`` (``ours``) to the first
  gradient step: every distinct omcrl function called with the :class:`~omcrl.config.Config` (or a copy) or one of
  its sections (``cfg.rl``, ``cfg.env``, ...) as an argument, by file;
* ``pipeline``: the lines of ``omcrl/pipeline/*.py`` and those of them inside string literals (the pages' prose).

It reads the code it runs (the checkout it is started from: ``cd`` into a worktree to measure another commit).
"""

from __future__ import annotations

import argparse
import ast
import inspect
import io
import json
import sys
import tempfile
import tokenize
from collections import Counter
from pathlib import Path

ROOT = Path.cwd()
sys.path.insert(0, str(ROOT))


class _Reached(Exception):
    """Raised at the gradient step being measured: the run stops there."""


def _omcrl_frames(frame) -> list:
    """The omcrl frames of a stack, outermost first."""
    out = []
    while frame is not None:
        if "/omcrl/" in frame.f_code.co_filename and "/scripts/" not in frame.f_code.co_filename:
            out.append(frame)
        frame = frame.f_back
    return out[::-1]


def _code_lines(src: list[str]) -> int:
    """Lines of a function's source that are code: its docstring, comments and blank lines aside."""
    import textwrap

    text = textwrap.dedent("".join(src))
    tree = ast.parse(text)
    fn = tree.body[0]
    skip: set[int] = set()
    body = getattr(fn, "body", [])
    if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
        skip.update(range(body[0].lineno, body[0].end_lineno + 1))
    lines = text.splitlines()
    return sum(
        1 for i, line in enumerate(lines, 1) if i not in skip and line.strip() and not line.strip().startswith("#")
    )


def _path(frames) -> dict:
    """Frames, files and lines of the functions on a stack (each function counted once)."""
    seen: dict[tuple[str, int], tuple[str, int]] = {}
    for f in frames:
        code = f.f_code
        key = (code.co_filename, code.co_firstlineno)
        if key not in seen:
            try:
                src = inspect.getsourcelines(code)[0]
            except OSError:
                src = []
            seen[key] = (f"{Path(code.co_filename).relative_to(ROOT)}:{code.co_qualname}", len(src), _code_lines(src))
    return {
        "frames": len(frames),
        "files": len({k[0] for k in seen}),
        "lines": sum(v[1] for v in seen.values()),
        "code_lines": sum(v[2] for v in seen.values()),
        "stack": [f"{name} ({n} lines, {c} of code)" for name, n, c in seen.values()],
    }


def _run_until_step(argv: list[str], want: callable) -> dict:
    """Run the CLI with ``argv`` until the first optimizer step at which ``want(frames)``; the stack there."""
    import torch

    from omcrl.__main__ import main

    found: dict = {}
    original = torch.optim.Adam.step

    def step(self, *a, **k):
        frames = _omcrl_frames(sys._getframe(1))
        if want(frames):
            found.update(_path(frames))
            raise _Reached
        return original(self, *a, **k)

    torch.optim.Adam.step = step
    try:
        main([*argv, "--debug"])
    except _Reached:
        pass
    finally:
        torch.optim.Adam.step = original
    if not found:
        raise SystemExit(f"code_reading: {' '.join(argv)} reached no gradient step")
    return found


def _method_of(frames) -> str | None:
    for f in frames:
        run = f.f_locals.get("run") or f.f_locals.get("run_rec")
        if run is not None and hasattr(run, "method"):
            return run.method
    return None


def _cfg_stops(argv: list[str]) -> dict:
    """Every omcrl function that receives a Config from train_method (ours) to the first gradient step."""
    import torch

    from omcrl.__main__ import main
    from omcrl.config import Config

    stops: dict[str, str] = {}
    state = {"on": False}

    def prof(frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        if code.co_name == "train_method" and code.co_filename.endswith("pipeline/recipes.py"):
            state["on"] = True
        if not state["on"] or "/omcrl/" not in code.co_filename:
            return
        args = [frame.f_locals.get(n) for n in code.co_varnames[: code.co_argcount + code.co_kwonlyargcount]]
        # The config or one of its sections (cfg.rl, cfg.env, ...): the classes of omcrl.config.
        if any(isinstance(a, Config) or type(a).__module__ == "omcrl.config" for a in args):
            stops.setdefault(f"{Path(code.co_filename).relative_to(ROOT)}:{code.co_qualname}", "")

    original = torch.optim.Adam.step

    def step(self, *a, **k):
        if state["on"]:
            raise _Reached
        return original(self, *a, **k)

    torch.optim.Adam.step = step
    sys.setprofile(prof)
    try:
        main([*argv, "--debug"])
    except _Reached:
        pass
    finally:
        sys.setprofile(None)
        torch.optim.Adam.step = original
    by_file = Counter(s.split(":")[0] for s in stops)
    in_runs_utils = sum(n for f, n in by_file.items() if f == "omcrl/runs.py" or f.startswith("omcrl/utils/"))
    return {"stops": len(stops), "in_runs_and_utils": in_runs_utils, "by_file": dict(by_file.most_common())}


def _pipeline_lines() -> dict:
    """Lines of omcrl/pipeline/*.py, and those inside string literals (docstrings excluded)."""
    total, prose = 0, 0
    per_file = {}
    for path in sorted((ROOT / "omcrl" / "pipeline").glob("*.py")):
        text = path.read_text(encoding="utf-8")
        n = len(text.splitlines())
        docstrings = set()
        for node in ast.walk(ast.parse(text)):
            body = getattr(node, "body", None)
            if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
                if isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
                    docstrings.add(body[0].lineno)
        lines: set[int] = set()
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if (
                tok.type in (tokenize.STRING, getattr(tokenize, "FSTRING_MIDDLE", -1))
                and tok.start[0] not in docstrings
            ):
                lines.update(range(tok.start[0], tok.end[0] + 1))
        total += n
        prose += len(lines)
        per_file[path.name] = {"lines": n, "string_lines": len(lines)}
    return {"lines": total, "string_lines": prose, "files": per_file}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, help="write the figures here too")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="omcrl-reading-") as tmp:
        common = ["--preset", "smoke", "--set", f"results_dir={tmp}", "--set", f"data.file={tmp}/data.h5"]
        from omcrl.__main__ import main as cli

        if cli(["collect", *common]) != 0:
            raise SystemExit("code_reading: collect failed")
        out = {"path/pretrain": _run_until_step(["pretrain", *common], lambda fr: True)}
        if cli(["pretrain", *common]) != 0 or cli(["train", "--method", "oracle", *common]) != 0:
            raise SystemExit("code_reading: the encoder or the oracle failed")
        out["path/train"] = _run_until_step(["train", "--method", "ours", *common], lambda fr: _method_of(fr) == "ours")
        out["cfg"] = _cfg_stops(["train", "--method", "ours", *common])
    out["pipeline"] = _pipeline_lines()
    for k in ("path/pretrain", "path/train"):
        p = out[k]
        print(f"{k}: {p['frames']} frames, {p['files']} files, {p['lines']} lines ({p['code_lines']} of code)")
        for s in p["stack"]:
            print(f"    {s}")
    c = out["cfg"]
    print(f"cfg: {c['stops']} stops, {c['in_runs_and_utils']} in runs.py and utils/; {c['by_file']}")
    pl = out["pipeline"]
    print(f"pipeline/: {pl['lines']} lines, {pl['string_lines']} in string literals (docstrings aside)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
