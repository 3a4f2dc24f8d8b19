"""Notebooks: committed ones are clean, and the runner executes them with papermill (smoke preset).

The chain test runs every notebook in order in one test, since later notebooks read what earlier ones wrote.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import nbformat
import pytest
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

from omcrl.pipeline import notebooks as nbr
from omcrl.pipeline.notebooks import (
    NOTEBOOKS,
    NotebookExecutionError,
    NotebookNotFoundError,
    check_notebook,
    run_chain,
    run_notebook,
    strip_outputs,
)

pytestmark = pytest.mark.notebooks

NO_NOTEBOOKS = "notebooks/ has no NN_*.ipynb yet"


def _write(path: Path, cells: list, params: str = 'preset = "smoke"\nresults_dir = "results"\n') -> Path:
    p = new_code_cell(params)
    p.metadata["tags"] = ["parameters"]
    nb = new_notebook(cells=[new_markdown_cell("# test"), p, *cells])
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.write(nb, str(path))
    return path


# ---------------------------------------------------------------- committed notebooks
def test_notebook_list_is_ordered(repo_root):
    found = sorted(p.stem for p in (repo_root / "notebooks").glob("[0-9][0-9]_*.ipynb"))
    assert found == NOTEBOOKS


@pytest.mark.parametrize("name", NOTEBOOKS or [pytest.param(None, marks=pytest.mark.skip(reason=NO_NOTEBOOKS))])
def test_committed_notebook_is_clean(repo_root, name):
    problems = check_notebook(repo_root / "notebooks" / f"{name}.ipynb")
    assert problems == [], f"{name}: {problems} (fix with: python -m omcrl.pipeline.notebooks strip)"


# ---------------------------------------------------------------- helpers
def test_strip_outputs(tmp_path):
    path = _write(tmp_path / "00_x.ipynb", [new_code_cell("print(1)")])
    nb = nbformat.read(str(path), as_version=4)
    nb.cells[2].outputs = [nbformat.v4.new_output("stream", name="stdout", text="1\n")]
    nb.cells[2].execution_count = 3
    nb.cells[2].metadata["papermill"] = {"duration": 1.0}
    nb.metadata["papermill"] = {"parameters": {}}
    nbformat.write(nb, str(path))
    assert check_notebook(path)
    assert strip_outputs(path) is True
    assert check_notebook(path) == []
    assert strip_outputs(path) is False  # idempotent: nothing left to change


def test_check_notebook_wants_one_parameters_cell_with_preset(tmp_path):
    path = _write(tmp_path / "00_x.ipynb", [], params="seed = 1\n")
    assert any("preset" in p for p in check_notebook(path))
    nb = nbformat.read(str(path), as_version=4)
    nb.cells[1].metadata["tags"] = []
    nbformat.write(nb, str(path))
    assert any("exactly one" in p for p in check_notebook(path))


def test_kernel_runs_this_interpreter():
    from jupyter_client.kernelspec import KernelSpecManager

    name, extra = nbr.resolve_kernel()
    if extra is None:
        spec = KernelSpecManager().get_kernel_spec(name)
        assert nbr._is_current_python(spec.argv[0])
    else:
        spec = json.loads((Path(extra) / "kernels" / name / "kernel.json").read_text())
        assert spec["argv"][0] == sys.executable


def test_missing_notebook_is_named(tmp_path):
    with pytest.raises(NotebookNotFoundError, match="99_nothing"):
        run_notebook("99_nothing", "smoke", results_dir=tmp_path)


def test_chain_selection_only_and_skip():
    full = nbr.select_notebooks()
    assert full == NOTEBOOKS
    no_ablations = nbr.select_notebooks(skip=["06"])
    assert "06_ablations" not in no_ablations and len(no_ablations) == len(NOTEBOOKS) - 1
    assert nbr.select_notebooks(only=["07_tables", "05"]) == ["05_train_baselines", "07_tables"]  # numeric order
    with pytest.raises(NotebookNotFoundError, match="--skip 6x"):
        nbr.select_notebooks(skip=["6x"])
    with pytest.raises(NotebookNotFoundError, match="leaves no notebook"):
        nbr.select_notebooks(only=["05"], skip=["05"])


def test_cli_bad_skip_fails_before_any_work(tmp_path, capsys):
    from omcrl.__main__ import main

    rc = main(["notebooks", "--preset", "smoke", "--skip", "66", "--set", f"results_dir={tmp_path}"])
    assert rc == 1
    assert "--skip 66" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------- running (starts real kernels)
def test_run_notebook_injects_parameters(tmp_path):
    src = _write(
        tmp_path / "00_probe.ipynb",
        [
            new_code_cell(
                "import json, os, sys\n"
                "probe = {'preset': preset, 'results_dir': results_dir, 'extra': extra,\n"
                "         'exe': sys.executable, 'cwd': os.getcwd()}\n"
                "json.dump(probe, open(os.path.join(results_dir, 'probe.json'), 'w'))"
            )
        ],
        params='preset = "quick"\nresults_dir = "results"\nextra = 0\n',
    )
    out = run_notebook(src, "smoke", parameters={"extra": 5}, results_dir=tmp_path / "res", cwd=tmp_path)
    assert out == tmp_path / "res" / "smoke" / "executed" / "00_probe.ipynb"
    probe = json.loads((tmp_path / "res" / "probe.json").read_text())
    assert probe["preset"] == "smoke" and probe["extra"] == 5
    assert probe["results_dir"] == str(tmp_path / "res")
    assert Path(probe["exe"]).parent == Path(sys.executable).parent
    assert Path(probe["cwd"]).resolve() == tmp_path.resolve()
    # the committed source stays clean; the executed copy has the injected cell
    assert check_notebook(src) == []
    executed = nbformat.read(str(out), as_version=4)
    assert any("injected-parameters" in c.metadata.get("tags", []) for c in executed.cells)


def test_failing_cell_is_named(tmp_path):
    src = _write(tmp_path / "00_broken.ipynb", [new_code_cell("x = 1"), new_code_cell("raise ValueError('boom 42')")])
    with pytest.raises(NotebookExecutionError) as e:
        run_notebook(src, "smoke", results_dir=tmp_path, cwd=tmp_path)
    msg = str(e.value)
    assert "00_broken" in msg and "cell 4" in msg and "ValueError" in msg and "boom 42" in msg
    assert e.value.cell == 4 and e.value.executed.is_file()


@pytest.mark.timeout(3600)
@pytest.mark.skipif(not NOTEBOOKS, reason=NO_NOTEBOOKS)
def test_chain_smoke(tmp_path, tello_ports):
    """Every notebook, in order, with the smoke preset, into a temporary results folder."""
    # Notebook 09 flies a Tello double on the SDK's fixed ports: only it runs under the machine's lock on them.
    flies = [n for n in NOTEBOOKS if n.startswith("09_")]
    outs = run_chain("smoke", [n for n in NOTEBOOKS if n not in flies], results_dir=tmp_path, verbose=True)
    with tello_ports():
        outs += run_chain("smoke", flies, results_dir=tmp_path, verbose=True)
    assert [p.stem for p in outs] == NOTEBOOKS
    for p in outs:
        assert p.is_file() and p.parent == tmp_path / "smoke" / "executed"
        nb = nbformat.read(p, as_version=4)
        errors = [o for c in nb.cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
        assert not errors, f"{p.name}: {errors[0].get('ename')}: {errors[0].get('evalue')}"
    # What the chain is for: Table I over every method and scene of the suite, its figures and the summary.
    import pandas as pd

    from omcrl.config import load_config
    from omcrl.pipeline.grids import CONTROL_METHODS
    from omcrl.rl.methods import TABLE1_METHODS

    root = tmp_path / "smoke"
    table = pd.read_csv(root / "tables" / "table1.csv")
    scenes = load_config("smoke").eval.scenes
    # The chain trains the paper's comparison; the controls (issue 75) are the grid's rows, not the notebooks'.
    assert set(table["method"]) == set(TABLE1_METHODS) - set(CONTROL_METHODS) and set(table["scene"]) == set(scenes)
    assert set(table["metric"]) == {"NE", "OS", "SR", "SPL", "CR", "TTS"} and table["episodes"].min() >= 1
    sr = table[table.metric == "SR"]["mean"]
    assert sr.between(0, 100).all()
    figures = {f.stem for f in (root / "figures").glob("*.png")}
    assert len(figures) >= 20 and all(f.stat().st_size > 5_000 for f in (root / "figures").glob("*.png"))
    # The summary as `python -m omcrl notebooks` ends the chain (notebook 07 writes one before 08 and 09 ran).
    from omcrl.pipeline.summary import write_summary

    summary = write_summary(load_config("smoke", overrides=[f"results_dir={tmp_path}"])).read_text()
    assert "not run yet" not in summary and "| SR | success rate |" in summary
    _reference_round_trip(tmp_path)


def _reference_round_trip(tmp_path):
    """The chain's runs packed as a reference bundle, unpacked into a fresh results folder: the run registry finds
    every Table I run there and Table I is rebuilt from the bundle alone. Exact: row for row the chain's table.
    Rounded to float16 (the default): re-keyed runs the registry still finds, their episodes flown once at packing."""
    import pandas as pd

    from omcrl.config import load_config
    from omcrl.eval.table1 import tables_stage
    from omcrl.pipeline.grids import CONTROL_METHODS
    from omcrl.pipeline.reference import pack_reference, unpack_reference
    from omcrl.rl.methods import METHODS, TABLE1_METHODS
    from omcrl.runs import find_runs

    cfg = load_config("smoke", overrides=[f"results_dir={tmp_path}"])
    paper = [m for m in TABLE1_METHODS if METHODS[m].learned and m not in CONTROL_METHODS]  # a bundle's default
    learned = sorted(f"{m}/seed{s}" for m in paper for s in cfg.seeds)
    key = ["method", "train_seed", "scene", "episode"]
    original = pd.read_csv(cfg.run_root / "tables" / "table1_episodes.csv").sort_values(key, ignore_index=True)
    for rounded in (False, True):
        name = "rounded" if rounded else "exact"
        packed = pack_reference(cfg, out=tmp_path / f"bundle-{name}", rounded=rounded, progress=False)
        files = packed.manifest["files"]
        assert files and not [f for f in files if f.endswith("checkpoint.pt") or "/tb/" in f]
        assert any(f.startswith("runs/pretrain/") and f.endswith("encoder.pt") for f in files)  # upstream came along
        fresh = load_config("smoke", overrides=[f"results_dir={tmp_path / name}"])
        res = unpack_reference(fresh, tmp_path / f"bundle-{name}")
        assert sorted(res.found) == learned and not res.not_found, name
        t = tables_stage(fresh, progress=False)
        assert not t.missing
        evals = {p.relative_to(fresh.run_root).as_posix() for p in (fresh.run_root / "eval").rglob("*") if p.is_file()}
        assert evals == {f for f in files if f.startswith("eval/")}, name  # nothing was flown again
        got = pd.read_csv(fresh.run_root / "tables" / "table1_episodes.csv").sort_values(key, ignore_index=True)
        if not rounded:
            pd.testing.assert_frame_equal(original, got)
            continue
        # Rounded: every artifact changed, so every run downstream of one got a new key, and says where it came from.
        keys = {r["dir"].parent.name for r in find_runs(cfg.run_root)}
        new = find_runs(fresh.run_root)
        assert all(r["reference"]["rounded_to"] == "float16" and r["reference"]["from_key"] in keys for r in new)
        assert any(r["dir"].parent.name not in keys for r in new)  # re-keyed: students name the rounded encoder
        effect = packed.manifest["rounding"]
        assert effect["episodes"] == int(original["method"].map(lambda m: METHODS[m].learned).sum())
        assert 0 <= effect["changed_success"] <= effect["episodes"]
        # The same bundle packed in parts (a grid packs each method as its run finishes) and merged: file for file
        # the whole one, the oracle that two parts carry (upstream of its students) stored once.
        from omcrl.pipeline.reference import merge_bundles

        names = paper
        parts = [
            pack_reference(cfg, methods=ms, out=tmp_path / "parts" / ms[0], progress=False).bundle
            for ms in (names[:2], names[2:])
        ]
        merged = merge_bundles(parts, tmp_path / "bundle-merged").manifest
        assert merged["files"] == files and merged["methods"] == packed.manifest["methods"]
        assert merged["rounding"]["episodes"] == effect["episodes"]
        assert merged["rounding"]["changed_success"] == effect["changed_success"]
