"""Structure (issue: a one-way library under an orchestration layer): the import contracts, the function-level
imports that remain and why, and the run keys of every Table I configuration unchanged by the refactor."""

from __future__ import annotations

import ast
import itertools
import json
import sys
from collections import Counter
from pathlib import Path

import grimp
import pytest

from omcrl.scenes import suite_overrides

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "omcrl"

# Function-level imports of omcrl kept on purpose, each for a measured import cost (docs/ARCHITECTURE.md):
ALLOWED_FUNCTION_IMPORTS = {
    # The CLI's error types and method list load PyTorch (~1.2 s); `--help` and a wrong argument do not wait.
    "omcrl/__main__.py": 15,
    # PyBullet loads in the evaluation worker that flies, not with omcrl.eval (~1.8 s for every table reader).
    "omcrl/eval/runner.py": 1,
    # The chain's summary: reproduce.sh checks --only / --skip through this module before any work (0.36 s, against
    # 8.4 s with the summary's PyTorch and evaluation stack under two training runs).
    "omcrl/pipeline/notebooks.py": 1,
    # method_color's label lookup: `import omcrl.viz` stays free of PyTorch (0.05 s against ~1.4 s).
    "omcrl/viz/__init__.py": 1,
}


def _top(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else module


def test_import_contracts_are_kept():
    """The layers of pyproject.toml's [tool.importlinter]: no module imports a layer above its own."""
    from importlinter.cli import lint_imports

    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True) == 0


def test_no_package_imports_run_in_a_circle():
    graph = grimp.build_graph("omcrl", exclude_type_checking_imports=True)
    edges: dict[str, set[str]] = {}
    for m in graph.modules:
        for imported in graph.find_modules_directly_imported_by(m):
            a, b = _top(m), _top(imported)
            if a != b and b != "omcrl":
                edges.setdefault(a, set()).add(b)

    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            n = todo.pop()
            for nxt in edges.get(n, ()):
                if nxt == goal:
                    return True
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return False

    circles = sorted((a, b) for a, bs in edges.items() for b in bs if reaches(b, a))
    assert circles == [], f"packages importing each other (directly or through others): {circles}"


def function_level_imports(root: Path = PACKAGE) -> Counter:
    """``{file: count}`` of ``import omcrl...`` statements inside a function body."""
    out: Counter = Counter()
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if (
                    isinstance(node, ast.ImportFrom) and (node.level > 0 or (node.module or "").startswith("omcrl"))
                ) or (isinstance(node, ast.Import) and any(a.name.split(".")[0] == "omcrl" for a in node.names)):
                    out[str(path.relative_to(root.parent))] += 1
    return out


def test_function_level_imports_are_only_the_justified_ones():
    found = dict(function_level_imports())
    assert found == ALLOWED_FUNCTION_IMPORTS, (
        "a function-level import of omcrl hides a dependency from the import contracts; import at module level "
        "(or, for a measured import cost, list it in ALLOWED_FUNCTION_IMPORTS with the reason)"
    )


def table1_run_keys(results_dir: Path) -> dict[str, str]:
    """The run folder names of every Table I configuration: presets × seeds 0–2 × learned methods (encoders,
    oracles and policies). Upstream artifacts are stood in by fixed bytes (policy keys take their digests)."""
    import omcrl.rl.methods as M
    from omcrl.config import load_config
    from omcrl.pretrain.train import pretrain_run
    from omcrl.rl.train import oracle_run, policy_run

    out = {}
    for suite, preset, seed in itertools.product(("v1", "v2"), ("smoke", "quick", "paper"), (0, 1, 2)):
        cfg = load_config(preset, overrides=[f"results_dir={results_dir}", *suite_overrides(suite)]).with_seed(seed)
        oracle = results_dir / f"oracle-{preset}-{seed}.pt"
        oracle.write_bytes(f"oracle {preset} {seed}".encode())
        out[f"{suite}/{preset}/seed{seed}/oracle"] = oracle_run(cfg).dir.parent.name
        for m in M.TABLE1_METHODS:
            spec = M.METHODS[m]
            if not spec.learned or spec.features == "oracle":
                continue
            enc = None
            if spec.features == "frozen":
                out[f"{suite}/{preset}/seed{seed}/{m}/encoder"] = pretrain_run(
                    M.encoder_config(cfg, spec)
                ).dir.parent.name
                enc = results_dir / f"enc-{preset}-{seed}-{m}.pt"
                enc.write_bytes(f"encoder {preset} {seed} {m}".encode())
            orc = oracle if spec.guide == "oracle" else None
            run = policy_run(cfg, spec.name, enc, orc, M.planner_factory(cfg, spec.guide))
            out[f"{suite}/{preset}/seed{seed}/{m}"] = run.dir.parent.name
    return out


def test_run_keys_of_every_table1_configuration_are_unchanged(tmp_path):
    """Keys of the one identity rule (issue 43; tests/data/run_keys_table1.json, v1 and v2 suites). A change that
    moves one must be intended: rewrite the file with ``table1_run_keys`` and say so in the commit."""
    pinned = json.loads((ROOT / "tests" / "data" / "run_keys_table1.json").read_text())
    now = table1_run_keys(tmp_path)
    assert len(now) == 324  # 2 suites × 3 presets × 3 seeds × (oracle, 10 students, their 7 encoders)
    assert now == pinned


@pytest.mark.parametrize("module", ["omcrl.config", "omcrl.scenes", "omcrl.pipeline.registry", "omcrl.viz"])
def test_light_modules_stay_free_of_torch(module):
    """What the CLI's help, config validation and figure helpers import loads neither PyTorch nor PyBullet."""
    import subprocess

    code = f"import sys, {module}; print(sorted(m for m in ('torch', 'pybullet') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", f"{module} loads {out.strip()}"


def test_a_new_method_kind_is_one_recipe_class_and_one_registry_row(tmp_path, monkeypatch):
    """Worked example (docs/extending.md): a student on a *random*, untrained frozen encoder — the control that
    asks whether pretraining matters. One Recipe subclass and one MethodSpec row; then the kit's ordinary entry
    points train it, find its run, fly it and evaluate it, with no other file touched."""
    import omcrl.rl.methods as M
    from omcrl.config import load_config
    from omcrl.eval.stage import evaluate_methods
    from omcrl.models import random_encoder, save_encoder
    from omcrl.pipeline import train_method
    from omcrl.rl.train import policy_run, train_visuomotor

    class RandomEncoderRecipe(M.Recipe):
        kind = "random-frozen"
        camera = True

        def encoder(self, cfg):
            path = cfg.run_root / "encoders" / f"random-seed{cfg.seed}.pt"
            if not path.exists():
                enc = random_encoder(cfg, seed=cfg.seed)
                save_encoder(path, enc.f, enc.phi, cfg)
            return path

        def run(self, cfg, spec):
            return policy_run(cfg, spec.name, self.encoder(cfg))

        def train(self, cfg, spec, needs, **common):
            return train_visuomotor(cfg, self.encoder(cfg), None, **common)

    monkeypatch.setattr(M, "RECIPES", dict(M.RECIPES))  # the registries as they were after the test
    monkeypatch.setattr(M, "METHODS", dict(M.METHODS))
    M.register_recipe(RandomEncoderRecipe())
    M.register_method(M.MethodSpec("random-enc", "Random encoder", "random-frozen", ablation=True))

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}", "rl.total_steps=128", "eval.episodes=2"])
    result = train_method(cfg, "random-enc", progress=False)
    path = M.final_policy_path(cfg, "random-enc")
    assert path == result.final_path and path.exists()
    assert train_method(cfg, "random-enc", progress=False).skipped  # the registry finds the finished run
    agent = M.get_method("random-enc").recipe.make_agent(cfg, M.get_method("random-enc"))
    assert agent.act is not None
    episodes = evaluate_methods(cfg, {"random-enc": path}, ["box"])
    assert len(episodes) == 2 and set(episodes["method"]) == {"random-enc"}
    with pytest.raises(Exception, match="no recipe"):
        M.register_method(M.MethodSpec("nope", "Nope", "no-such-kind"))


def test_the_grids_controls_are_the_methods_marked_control():
    """The grids' controls (derived from the methods table) are the methods marked control, in Table I's order."""
    from omcrl.pipeline.grids import CONTROL_METHODS
    from omcrl.rl.methods import METHODS

    assert set(CONTROL_METHODS) == {n for n, s in METHODS.items() if s.control} == {"ours-random", "ours-blind"}
