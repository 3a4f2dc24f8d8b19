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
from omcrl.eval.ablation import SUMMARY_COLUMNS, findings_summary
from omcrl.eval.metrics import glossary_markdown
from omcrl.eval.table1 import read_table1_csv
from omcrl.pipeline.expected import expected_time
from omcrl.pipeline.glance import update_readme, wide_table
from omcrl.pipeline.pages import render
from omcrl.pipeline.records import DataRecord, DeployRecord, OracleRecord, PretrainRecord, StudentRecord, Table1Record
from omcrl.scenes import PAPER_SUITE
from omcrl.utils.io import atomic_write_text
from omcrl.utils.progress import format_duration
from omcrl.utils.runtime import code_commit, machine_info


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
    """The Markdown text of ``results/<preset>/summary.md`` for ``cfg.preset`` (``templates/summary/``)."""
    root = cfg.run_root
    tables, figures = root / "tables", root / "figures"
    walls = _read_json(root / "executed" / "wall_times.json") or {}
    peaks = _read_json(root / "executed" / "peak_rss_mb.json") or {}
    table = ""
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
        table = _md_table(rows)
    sections = []
    for heading, source, what, notebook, body in SECTIONS:
        # A stage's record (its JSON, read through its type) or, for a table, just the file's presence.
        path = tables / (source.FILE if isinstance(source, type) else source)
        if not path.exists():
            sections.append((heading, _page("missing", what=what, notebook=notebook)))
            continue
        try:
            sections.append((heading, body(source.read(tables) if isinstance(source, type) else {}, tables)))
        except (OSError, ValueError, KeyError, TypeError, pd.errors.ParserError) as e:
            # A damaged table is one line in its section, never a crash of the whole summary.
            error = f"{type(e).__name__}: {' '.join(str(e).split())[:160]}"
            sections.append((heading, _page("unreadable", what=what, error=error)))
    text = _page(
        "page",
        preset=cfg.preset,
        written=time.strftime("%Y-%m-%d %H:%M %Z"),
        commit=code_commit(),
        machine=_machine(),
        root=root,
        seeds=cfg.seeds,
        steps=cfg.rl.total_steps,
        iterations=cfg.pretrain.iterations,
        episodes=cfg.eval.episodes,
        walls=table,
        sections=sections,
        figures=sorted(figures.glob("*.png")) if figures.is_dir() else [],
        glossary=glossary_markdown(),
    )
    return text + "\n"


def _page(name: str, **data: Any) -> str:
    """``templates/summary/<name>.md.j2`` filled with ``data``, as written (summary.md is not wrapped), without the
    blank line that ends it (the page puts one after every section)."""
    return render(f"summary/{name}.md.j2", layout=False, **data).rstrip("\n")


def _duration(s: float) -> str:
    return format_duration(float(s))


# Each section renders what one stage left in tables/: (d = its record, or {} for a table; tables folder).
def _section_data(d: DataRecord, tables: Path) -> str:
    sr = d.pilot_success_rate
    return _page("data", d=d, sr=_fmt(None if sr is None else 100 * sr))


def _section_pretrain(d: PretrainRecord, tables: Path) -> str:
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
    return _page("pretrain", table=_md_table(rows))


def _section_oracle(d: OracleRecord, tables: Path) -> str:
    ev = d.eval_box
    sr = _fmt(100 * d.final_success_rate if d.final_success_rate is not None else None)
    box = {k: _fmt(ev.get(k)) for k in ("SR", "SPL", "CR", "episodes")}
    return _page("oracle", steps=_fmt(d.steps), rate=_fmt(d.steps_per_s), sr=sr, box=box)


def _section_student(d: StudentRecord, tables: Path) -> str:
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
    return _page("table", table=_md_table(rows))


def _section_table1(d: dict, tables: Path) -> str:
    try:
        long = read_table1_csv(tables / "table1.csv")
    except ValueError as e:
        return _page("table1", error=e)
    s = Table1Record.read(tables) or Table1Record()
    cols = ("claim", "family", "hypotheses", "holds", "reversed", "undecided", "one seed", "not run", "verdict")
    claims = [
        {
            "claim": c["claim"],
            "scene": c["scene"],
            "difference": f"{c['diff']:.1f} [{c['lo']:.1f}, {c['hi']:.1f}]",
            "verdict": c["verdict"],
        }
        for c in s.claims
    ]
    return _page(
        "table1",
        error=None,
        sr=wide_table(long[long.metric == "SR"]),
        cr=wide_table(long[long.metric == "CR"]),
        ledger=_md_table([{k: c.get(k, "") for k in cols} for c in s.ledger]) if s.ledger else None,
        # A chain on one seed (the reference bundle's) judges nothing: say where the grid's verdicts are.
        one_seed={c.get("verdict") for c in s.ledger} in ({"one seed"}, {"one seed", "not run"}),
        preset=tables.parent.name,
        claims=_md_table(claims) if claims else None,
        missing=[str(m) for m in s.missing_runs or []],
    )


def _section_deploy(d: DeployRecord, tables: Path) -> str:
    latency = [f"{k} {_fmt(v.get('median_ms'))} / {_fmt(v.get('p99_ms'))}" for k, v in d.latency.items()]
    return _page("deploy", d=d, parity=_fmt(d.parity.get("max_abs_diff")), latency=latency,
                 distance=_fmt(d.sim_flight.get("final_distance")))  # fmt: skip


def _section_interpret(d: dict, tables: Path) -> str:
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
    extra = []
    for name, label in (("gradcam_mass.csv", "Grad-CAM mass on obstacles"), ("stability.csv", "Feature stability")):
        if (tables / name).exists():
            extra.append((label, _md_table(pd.read_csv(tables / name).round(3).to_dict("records")), name))
    return _page("interpret", disturbance=_md_table(rows), extra=extra)


def _section_ablations(d: dict, tables: Path) -> str:
    import pandas as pd

    verdicts = findings_summary(pd.read_csv(tables / "ablation_findings.csv"))
    names = sorted(p.name for p in tables.glob("*.md") if p.stem.startswith(("ablation_", "table2", "table3")))
    names = [n for n in names if n != "ablation_findings.md"]
    findings = None if verdicts.empty else _md_table(verdicts[SUMMARY_COLUMNS].to_dict("records"))
    return _page("ablations", findings=findings, names=names)


def _section_transfer(d: dict, tables: Path) -> str:
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
    blind = None
    if (tables / "transfer_blind.csv").exists():
        b = pd.read_csv(tables / "transfer_blind.csv")
        wide = b.pivot(index="method", columns="scene", values="SR")
        wide = wide.loc[list(dict.fromkeys(b.method)), list(dict.fromkeys(b.scene))]
        blind = _md_table(wide.round(0).reset_index().to_dict("records"))
    remedies = [(p.name, p.read_text(encoding="utf-8").strip()) for p in sorted(tables.glob("remedy_*.md"))]
    return _page("transfer", look=_md_table(rows), blind=blind, remedies=remedies)


def _section_gradient(_: Any, tables: Path) -> str:
    order = tables / "scene_gradient_order.md"
    extra = [
        (what, name, (tables / name).read_text(encoding="utf-8").strip())
        for name, what in (("scene_navigation.md", "Navigation per suite"), ("scene_criteria.md", "Suite criteria"))
        if (tables / name).exists()
    ]
    return _page(
        "gradient",
        suite=list(PAPER_SUITE),
        gradient=(tables / "scene_gradient.md").read_text(encoding="utf-8").strip(),
        order=order.read_text().strip() if order.exists() else None,
        extra=extra,
    )


# (heading, file in tables/ whose presence means the stage ran, what, notebook, renderer)
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
    "code_commit",
    "preset_banner",
    "summary_text",
    "table1_long",
    "write_summary",
]
