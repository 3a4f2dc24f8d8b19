"""The results summary of a preset: ``results/<preset>/summary.md``.

Written at the end of the notebook chain (``./reproduce.sh --quick``) and by ``python -m omcrl summary --preset
P``. It reads what the stages left in ``results/<preset>/`` (their records, :mod:`omcrl.pipeline.records`, in
``tables/*.json``; ``tables/table1.csv``; the
notebooks' wall times, ``figures/``) and says plainly what is missing; it never runs or trains anything, so it is
cheap to regenerate at any point of a run.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pandas as pd

from omcrl.config import Config
from omcrl.eval.ablation import findings_summary
from omcrl.eval.metrics import glossary_markdown
from omcrl.eval.table1 import read_table1_csv
from omcrl.pipeline.expected import expected_time
from omcrl.pipeline.glance import update_readme, wide_table
from omcrl.pipeline.records import DataRecord, DeployRecord, OracleRecord, PretrainRecord, StudentRecord, Table1Record
from omcrl.scenes import PAPER_SUITE
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import format_duration
from omcrl.utils.runtime import code_commit, machine_info

SMOKE_NOTE = (
    "**Smoke preset: these numbers only check the plumbing.** Every learned method trained a few hundred env "
    "steps and is evaluated on a handful of episodes, so success rates near 0 and wide intervals are expected. "
    "For numbers that mean something run the `quick` preset (`./reproduce.sh --quick`, a few hours on a laptop "
    "CPU; `docs/results.md` has a reference run), or `paper` on a GPU machine."
)


def preset_banner(preset: str, notebook: str | None = None) -> str:
    """The lines at the top of every notebook: its expected time at ``preset`` (when ``notebook`` is given) and,
    for ``smoke``, what its numbers mean."""
    lines = [expected_time(preset, notebook)] if notebook else []
    if preset == "smoke":
        lines.append(
            "smoke preset: every stage runs at a tiny scale (a few hundred env steps, a handful of episodes), so the "
            "numbers below only check the plumbing. For results that mean something run the quick preset "
            "(./reproduce.sh --quick, a few hours on a laptop CPU; reference numbers in docs/results.md)."
        )
    return "\n".join(lines)


NOTEBOOK_TITLES = {
    "00_scenes": "scenes",
    "01_collect_data": "data collection",
    "02_pretrain_encoder": "encoder pretraining (OMC, CURL)",
    "03_train_oracle": "oracle",
    "04_train_student": "student (ours, ours-noOT)",
    "05_train_baselines": "baselines (ppo, npe, npe-ot, curl, curl-phi)",
    "06_ablations": "ablations",
    "07_tables": "Table I",
    "08_interpretability": "interpretability",
    "09_deploy_tello": "deployment",
}


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _machine() -> str:
    import platform

    info = machine_info()
    import psutil
    import torch

    mem = f", {psutil.virtual_memory().total / 2**30:.0f} GiB RAM"

    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    return (
        f"{platform.system()} {platform.machine()}, {info['cpu_model']} ({info.get('cpu_capability', '?')} "
        f"kernels), {info['cpu_count']} CPU cores{mem}, {gpu}; Python {info['python']}, torch {torch.__version__}"
    )


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and v != v):
        return "–"
    if isinstance(v, float) and v.is_integer() and abs(v) >= 1000:
        return f"{int(v):,}"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _md_table(rows: list[dict]) -> str:
    if not rows:
        return ""
    cols = list(rows[0])
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |" for r in rows]
    return "\n".join(out)


def table1_long(csv_path: Path, metrics: tuple[str, ...] = ("SR", "SPL", "CR", "NE")) -> pd.DataFrame:
    """Table I in long, readable form: one row per scene and method, ``mean [lo, hi]`` per metric.

    Parameters
    ----------
    csv_path : ``tables/table1.csv`` (columns method, scene, metric, mean, lo, hi, seeds, episodes).
    metrics : which metrics to show, in this order.
    """
    df = read_table1_csv(csv_path)
    df = df[df["metric"].isin(metrics)]
    rows = []
    # Scenes, then methods, in the order the table file lists them (training scene first, ours early).
    order = {k: i for i, k in enumerate(dict.fromkeys(df["scene"]))}
    m_order = {k: i for i, k in enumerate(dict.fromkeys(df["method"]))}
    groups = df.groupby(["scene", "method"], sort=False)
    for scene, method in sorted(groups.groups, key=lambda k: (order[k[0]], m_order[k[1]])):
        g = groups.get_group((scene, method))
        row: dict[str, Any] = {"scene": scene, "method": method}
        for m in metrics:
            r = g[g["metric"] == m]
            if r.empty:
                continue
            r = r.iloc[0]
            d = 2 if m in ("SPL", "NE") else 1
            row[m] = "–" if pd.isna(r["mean"]) else f"{r['mean']:.{d}f} [{r['lo']:.{d}f}, {r['hi']:.{d}f}]"
        row["seeds × episodes"] = f"{int(g['seeds'].iloc[0])} × {int(g['episodes'].iloc[0])}"
        rows.append(row)
    return pd.DataFrame(rows)


def summary_text(cfg: Config) -> str:
    """The Markdown text of ``results/<preset>/summary.md`` for ``cfg.preset``."""
    root = cfg.run_root
    tables, figures = root / "tables", root / "figures"
    out = [f"# OMC-RL kit: results summary, preset `{cfg.preset}`", ""]
    if cfg.preset == "smoke":
        out += [SMOKE_NOTE, ""]
    out += [
        f"Written {time.strftime('%Y-%m-%d %H:%M %Z')} · commit {code_commit()} · {_machine()}",
        f"Results folder: `{root}` · training seeds {cfg.seeds} · {cfg.rl.total_steps:,} env steps per learned "
        f"method · {cfg.pretrain.iterations:,} pretraining iterations · {cfg.eval.episodes} evaluation episodes "
        "per scene",
        "",
        "## Wall time per stage",
        "",
    ]
    walls = _read_json(root / "executed" / "wall_times.json") or {}
    peaks = _read_json(root / "executed" / "peak_rss_mb.json") or {}
    if walls:
        rows = [
            {
                "notebook": n,
                "stage": NOTEBOOK_TITLES.get(n, ""),
                "wall time": _duration(s),
                "peak memory": f"{peaks[n]:,.0f} MB" if n in peaks else "",
            }
            for n, s in sorted(walls.items())
        ]
        rows.append(
            {
                "notebook": "total",
                "stage": "",
                "wall time": _duration(sum(walls.values())),
                "peak memory": f"{max(peaks.values()):,.0f} MB" if peaks else "",
            }
        )
        out += [_md_table(rows), ""]
        out += [
            "(last run of each notebook; a stage that reused finished runs is fast. Peak memory: the summed "
            "resident memory of the notebook's processes, sampled every 0.25 s.)",
            "",
        ]
    else:
        out += ["No notebook has run through `python -m omcrl notebooks` yet.", ""]

    for heading, source, what, notebook, body in SECTIONS:
        # A stage's record (its JSON, read through its type) or, for a table, just the file's presence.
        path = tables / (source.FILE if isinstance(source, type) else source)
        out += [heading, ""]
        if not path.exists():
            out += [f"_{what}: not run yet (notebook {notebook})._", ""]
            continue
        try:
            out += body(source.read(tables) if isinstance(source, type) else {}, tables)
        except (OSError, ValueError, KeyError, TypeError, pd.errors.ParserError) as e:
            # A damaged table is one line in its section, never a crash of the whole summary.
            out += [f"_{what}: cannot be read ({type(e).__name__}: {' '.join(str(e).split())[:160]})._", ""]

    out += ["## Figures", ""]
    figs = sorted(figures.glob("*.png")) if figures.is_dir() else []
    out += [f"- [{f.stem}](figures/{f.name})" for f in figs] or ["No figures yet."]
    out += ["", "## Metrics", "", glossary_markdown(), ""]
    return "\n".join(out)


def _duration(s: float) -> str:
    return format_duration(float(s))


# Each section renders what one stage left in tables/: (d = its record, or {} for a table; tables folder).
def _section_data(d: DataRecord, tables: Path) -> list[str]:
    sr = d.pilot_success_rate
    return [
        f"{d.episodes} episodes, {d.steps:,} steps in `{d.file}` ({d.file_mb:.1f} MB); "
        f"scripted pilot success rate {_fmt(None if sr is None else 100 * sr)} %.",
        "",
    ]


def _section_pretrain(d: PretrainRecord, tables: Path) -> list[str]:
    probe = d.probe_r2
    rows = []
    for name, r in d.encoders.items():
        rows.append(
            {
                "encoder": name,
                "iterations": r.get("iterations"),
                "final loss": r.get("final_loss"),
                "masked top-1 acc": r.get("final_accuracy"),
                "chance": r.get("chance_accuracy"),
                "probe R² (mean)": probe.get(name, {}).get("mean_r2"),
            }
        )
    if "random" in probe:
        rows.append({"encoder": "random (floor)", "probe R² (mean)": probe["random"].get("mean_r2")})
    return [
        _md_table(rows),
        "",
        "Masked top-1 acc: the share of masked frames whose reconstructed latent picks its own frame among the "
        "batch's candidates (chance: 1 / candidates). Probe R²: a linear map from the frozen features to the drone's "
        "state on held-out episodes (1 = perfect, 0 = no better than the mean); a random encoder gives the floor.",
        "",
    ]


def _section_oracle(d: OracleRecord, tables: Path) -> list[str]:
    ev = d.eval_box
    return [
        f"{_fmt(d.steps)} env steps at {_fmt(d.steps_per_s)} steps/s; training SR (last updates) "
        f"{_fmt(100 * d.final_success_rate if d.final_success_rate is not None else None)} %; "
        f"evaluation in box: SR {_fmt(ev.get('SR'))} %, SPL {_fmt(ev.get('SPL'))}, CR {_fmt(ev.get('CR'))} % "
        f"({_fmt(ev.get('episodes'))} episodes).",
        "",
    ]


def _section_student(d: StudentRecord, tables: Path) -> list[str]:
    rows = []
    for label, r in (("ours", d.guided), ("ours-noOT", d.unguided)):
        rows.append(
            {
                "method": label,
                "env steps": r.get("steps"),
                "steps/s": r.get("steps_per_s"),
                "final training SR %": None if r.get("final_success_rate") is None else 100 * r["final_success_rate"],
                "box SR % (eval)": d.box_SR.get(label),
            }
        )
    return [_md_table(rows), ""]


def _section_table1(d: dict, tables: Path) -> list[str]:
    try:
        long = read_table1_csv(tables / "table1.csv")
    except ValueError as e:
        return [f"_Table I cannot be read: {e}._", ""]
    out = [
        "Mean [95% CI] over training seeds and evaluation layouts (crossed factors); the paper's value in "
        "*italics*. Every method trained in box only; every other scene is zero-shot (furniture-v0: the stress "
        "test). Every metric (NE, OS, SR, SPL, CR, TTS): [tables/table1.md](tables/table1.md); beside the paper's: "
        "[tables/table1_vs_paper.md](tables/table1_vs_paper.md).",
        "",
        "Success rate (SR, %):",
        "",
        *wide_table(long[long.metric == "SR"]),
        "",
        "Collision rate (CR, %):",
        "",
        *wide_table(long[long.metric == "CR"]),
        "",
    ]
    s = Table1Record.read(tables) or Table1Record()
    claims = s.claims
    if s.ledger:
        out += ["### The paper's claims: the ledger's verdicts (Holm within the primary and the secondary family)", ""]
        cols = ("claim", "family", "hypotheses", "holds", "reversed", "undecided", "one seed", "not run", "verdict")
        out += [_md_table([{k: c.get(k, "") for k in cols} for c in s.ledger]), ""]
        out += ["Every hypothesis: [tables/ledger_verdicts.md](tables/ledger_verdicts.md).", ""]
    if claims:
        out += ["### The paper's orderings, checked here (SR, percentage points)", ""]
        out += [
            _md_table(
                [
                    {
                        "claim": c["claim"],
                        "scene": c["scene"],
                        "difference": f"{c['diff']:.1f} [{c['lo']:.1f}, {c['hi']:.1f}]",
                        "verdict": c["verdict"],
                    }
                    for c in claims
                ]
            ),
            "",
        ]
    if s.missing_runs:
        out += [f"Runs not found (not in the table): {', '.join(map(str, s.missing_runs))}.", ""]
    return out


def _section_deploy(d: DeployRecord, tables: Path) -> list[str]:
    lat, par, fl = d.latency, d.parity, d.sim_flight
    return [
        f"`{d.method}` exported to ONNX: parity max |Δ| {_fmt(par.get('max_abs_diff'))} over "
        f"{par.get('observations')} observations; latency median / p99 (ms): "
        + ", ".join(f"{k} {_fmt(v.get('median_ms'))} / {_fmt(v.get('p99_ms'))}" for k, v in lat.items())
        + f"; simulated flight ended by `{fl.get('reason')}` after {fl.get('ticks')} ticks, "
        f"{_fmt(fl.get('final_distance'))} m from the goal.",
        "",
    ]


def _section_interpret(d: dict, tables: Path) -> list[str]:
    import pandas as pd

    dist = pd.read_csv(tables / "disturbance.csv")
    rows = [
        {
            "method": r.method,
            "condition": r.condition,
            "SR [95% CI]": f"{r.SR:.0f} [{r.lo:.0f}, {r.hi:.0f}]",
            "paper (real)": "" if pd.isna(r.paper_SR) else f"{r.paper_SR:.0f}",
        }
        for r in dist.itertuples()
    ]
    out = ["Disturbance tests in the simulated room (SR %):", "", _md_table(rows), ""]
    explain = {
        "gradcam_mass.csv": "share: the Grad-CAM map's mass on obstacle pixels; obstacle_fraction: the part of the "
        "image obstacles cover (a uniform map's share); lift = share / obstacle_fraction (1: no more than uniform); "
        "frames_used: frames with both map mass and obstacles.",
        "stability.csv": "rel_distance: clean-to-disturbed cosine distance of the features over that between "
        "unrelated frames (0: the features did not move); knn_acc: the share of disturbed frames whose nearest "
        "clean feature is their own frame; clean_disturbed, unrelated: the two mean distances.",
    }
    for name, label in (("gradcam_mass.csv", "Grad-CAM mass on obstacles"), ("stability.csv", "Feature stability")):
        if (tables / name).exists():
            t = pd.read_csv(tables / name).round(3)
            out += [f"{label}:", "", _md_table(t.to_dict("records")), "", explain[name], ""]
    return out


def _section_ablations(d: dict, tables: Path) -> list[str]:
    import pandas as pd

    verdicts = findings_summary(pd.read_csv(tables / "ablation_findings.csv"))
    if verdicts.empty:
        out = ["None of the paper's ablation grids has run (a smoke grid checks the machinery only).", ""]
    else:
        out = [
            "The paper's six ablation findings, checked in SR in the paper's unseen scenes; the stress test "
            "(furniture-v0) is counted apart, held / reversed / undecided (`tables/ablation_findings.md`):"
        ]
        out += ["", _md_table(verdicts.to_dict("records")), ""]
    names = sorted(p.name for p in tables.glob("*.md") if p.stem.startswith(("ablation_", "table2", "table3")))
    names = [n for n in names if n != "ablation_findings.md"]
    if names:
        out += ["Tables (Table II = `table2.md`, Table III = `table3.md`): " + ", ".join(f"`{n}`" for n in names), ""]
    return out


def _section_transfer(d: dict, tables: Path) -> list[str]:
    import pandas as pd

    look = pd.read_csv(tables / "transfer_appearance.csv")
    rows = [
        {
            "layout": r.layout,
            "look": r.look,
            "seeds": r.seeds,
            "SR [95% CI]": f"{r.SR:.0f} [{r.SR_lo:.0f}, {r.SR_hi:.0f}]",
        }
        for r in look.itertuples()
    ]
    out = ["Student `ours` with each scene's layouts in its own look and in another (`tables/transfer_*.md`):", ""]
    out += [_md_table(rows), ""]
    if (tables / "transfer_blind.csv").exists():
        blind = pd.read_csv(tables / "transfer_blind.csv")
        wide = blind.pivot(index="method", columns="scene", values="SR")
        wide = wide.loc[list(dict.fromkeys(blind.method)), list(dict.fromkeys(blind.scene))]
        out += ["SR with vision and with the training scene's mean feature instead (goal seeking without vision):", ""]
        out += [_md_table(wide.round(0).reset_index().to_dict("records")), ""]
    for p in sorted(tables.glob("remedy_*.md")):
        out += [f"Remedies, `{p.name}`:", "", p.read_text(encoding="utf-8").strip(), ""]
    return out


# (heading, file in tables/ whose presence means the stage ran, what, notebook, renderer)
def _section_gradient(_: Any, tables: Path) -> list[str]:
    suite = ", ".join(PAPER_SUITE)
    out = [
        f"Scenes as versioned specs; the paper's suite is {suite}, with furniture-v0 (an unseen room) as a stress "
        "test. Shift from box with nothing learned, and navigation (`tables/scene_gradient.md`):",
        "",
        (tables / "scene_gradient.md").read_text(encoding="utf-8").strip(),
        "",
    ]
    order = tables / "scene_gradient_order.md"
    if order.exists():
        out += [f"Does each measure rise {' < '.join(PAPER_SUITE)}?", "", order.read_text().strip(), ""]
    for name, what in (("scene_navigation.md", "Navigation per suite"), ("scene_criteria.md", "Suite criteria")):
        if (tables / name).exists():
            out += [f"{what} (`tables/{name}`):", "", (tables / name).read_text(encoding="utf-8").strip(), ""]
    return out


SECTIONS = (
    (
        "## Scenes and their gradient of difficulty (notebook 00, `gradient`)",
        "scene_gradient.csv",
        "scene gradient",
        "00_scenes",
        _section_gradient,
    ),
    ("## Data (notebook 01)", DataRecord, "data", "01_collect_data", _section_data),
    ("## Pretraining (notebook 02)", PretrainRecord, "pretraining", "02_pretrain_encoder", _section_pretrain),
    ("## Oracle (notebook 03)", OracleRecord, "oracle", "03_train_oracle", _section_oracle),
    (
        "## Student: ours and ours-noOT (notebook 04)",
        StudentRecord,
        "student",
        "04_train_student",
        _section_student,
    ),
    ("## Ablations (notebook 06)", "ablation_findings.csv", "ablations", "06_ablations", _section_ablations),
    ("## Table I (notebook 07)", "table1.csv", "Table I", "07_tables", _section_table1),
    (
        "## Interpretability and disturbances (notebook 08)",
        "disturbance.csv",
        "interpretability",
        "08_interpretability",
        _section_interpret,
    ),
    (
        "## Zero-shot diagnosis and remedies (notebook 08, `transfer`, `sweep remedy-*`)",
        "transfer_appearance.csv",
        "zero-shot diagnosis",
        "08_interpretability",
        _section_transfer,
    ),
    ("## Deployment (notebook 09)", DeployRecord, "deployment", "09_deploy_tello", _section_deploy),
)


def write_summary(cfg: Config) -> Path:
    """Write ``results/<preset>/summary.md`` (atomically) and return its path."""
    path = cfg.run_root / "summary.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, summary_text(cfg))
    return path


def summary_stage(cfg: Config, readme: bool = False) -> None:
    """CLI stage ``summary``: write the summary of ``cfg.preset`` and print it; with ``readme``, rewrite the
    README's "Results at a glance" from ``reference/<preset>/table1`` instead (:mod:`omcrl.pipeline.glance`)."""
    if readme:
        changed = update_readme(cfg.preset)
        print(f"[omcrl] README.md: results at a glance {'rewritten' if changed else 'already current'}", flush=True)
        return
    path = write_summary(cfg)
    print(path.read_text(encoding="utf-8"))
    print(f"[omcrl] summary: {path}", flush=True)


__all__ = [
    "SMOKE_NOTE",
    "code_commit",
    "preset_banner",
    "summary_text",
    "table1_long",
    "write_summary",
]
