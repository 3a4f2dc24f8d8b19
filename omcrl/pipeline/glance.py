"""The README's "Results at a glance": the reference Table I (success rate with its CI over seeds, the paper's value
beside) and one line per claim of the paper, rendered from the committed reference tables.

The reference tables live in ``reference/<preset>/table1/`` (``table1.csv``, long rows as the ``tables`` stage
writes them, and ``table1_summary.json``, notebook 07's :class:`~omcrl.pipeline.records.Table1Record` with the
claims). ``python -m omcrl summary --preset quick --readme`` rewrites the block between the README's markers;
``tests/test_summary.py`` fails when the README differs from what these files give, so the two cannot drift apart.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from omcrl.config import project_root
from omcrl.eval.table1 import paper_table1, read_table1_csv
from omcrl.pipeline.records import Table1Record
from omcrl.rl.methods import METHODS
from omcrl.scenes import scene_label, scene_spec
from omcrl.utils.io import atomic_write_text

START = "<!-- results-at-a-glance: start (python -m omcrl summary --preset quick --readme writes this block) -->"
END = "<!-- results-at-a-glance: end -->"


class GlanceError(RuntimeError):
    """The reference tables or the README's markers are missing or malformed; the message names the file."""


def reference_table_dir(preset: str) -> Path:
    """``<checkout>/reference/<preset>/table1``: the reference Table I the README shows."""
    return project_root() / "reference" / preset / "table1"


def _read(table_dir: Path) -> tuple[pd.DataFrame, Table1Record]:
    csv, js = table_dir / "table1.csv", table_dir / Table1Record.FILE
    for f in (csv, js):
        if not f.is_file():
            raise GlanceError(f"{f}: missing; the reference Table I is made by python -m omcrl reference --pack")
    try:
        table, record = read_table1_csv(csv), Table1Record.read(table_dir)
    except ValueError as e:  # CorruptFile included
        raise GlanceError(str(e)) from None
    return table[table.metric == "SR"], record


def _signed(x: float) -> str:
    return f"{x:+.0f}".replace("-", "−")


def wide_table(rows: pd.DataFrame, with_paper: bool = True, digits: int = 0) -> list[str]:
    """Markdown lines of one metric of Table I, one row per method, one column per scene: ``mean [lo, hi]`` (the
    CI left out where it collapses), with the paper's value in *italics* where it has one (``with_paper``).

    Parameters
    ----------
    rows : Table I's long rows of one metric (columns method, scene, metric, mean, lo, hi), e.g. SR in %.
    """
    methods = list(dict.fromkeys(rows["method"]))
    scenes = list(dict.fromkeys(rows["scene"]))
    metric = str(rows["metric"].iloc[0]) if len(rows) else "SR"
    paper = paper_table1().set_index(["method", "scene"])[metric]
    cell = {(r.method, r.scene): r for r in rows.itertuples()}

    def num(x: float) -> str:
        return "–" if not math.isfinite(x) else f"{x:.{digits}f}"

    lines = ["| method | " + " | ".join(scene_label(s) for s in scenes) + " |", "|---|" + "---|" * len(scenes)]
    for m in methods:
        out = []
        for s in scenes:
            r = cell.get((m, s))
            if r is None:
                out.append("")
                continue
            text = num(r.mean)
            if math.isfinite(r.lo) and math.isfinite(r.hi) and (num(r.lo), num(r.hi)) != (text, text):
                text += f" [{num(r.lo)}, {num(r.hi)}]"
            psc = scene_spec(s).paper_scene
            if with_paper and psc is not None and (m, psc) in paper.index and pd.notna(paper[(m, psc)]):
                text += f" *{paper[(m, psc)]:g}*"
            out.append(text)
        lines.append(f"| {METHODS[m].label if m in METHODS else m} | " + " | ".join(out) + " |")
    return lines


def render_glance(table_dir: str | Path, figure: str = "docs/figures/quick/v1/fig5_training_curves.png") -> str:
    """The markdown block (without the markers) for the reference Table I in ``table_dir``."""
    sr, record = _read(Path(table_dir))
    seeds, n = int(sr["seeds"].max()), int(sr["episodes"].min())
    lines = [
        f"Success rate % over {seeds} training seeds × {n} episodes per scene, mean [95 % CI] (two-stage bootstrap); "
        "the paper's value (200 episodes, Unity scenes) in *italics*. Trained in box only; every other scene unseen.",
        "",
        *wide_table(sr),
    ]
    claims = pd.DataFrame(record.claims)
    if len(claims):
        lines += ["", "The paper's orderings (SR difference in points [95 % CI]; a verdict where the CI excludes 0):"]
        lines.append("")
        for claim, g in claims.groupby("claim", sort=False):
            parts = []
            for verdict in ("holds", "reversed", "undecided"):
                sc = g[g.verdict == verdict]
                if len(sc):
                    where = ", ".join(
                        f"{r.scene} {_signed(r.diff)} [{_signed(r.lo)}, {_signed(r.hi)}]" if verdict != "undecided"
                        else r.scene
                        for r in sc.itertuples()
                    )  # fmt: skip
                    parts.append(f"**{verdict}** in {where}")
            lines.append(f"- `{claim}`: " + "; ".join(parts) + ".")
    lines += ["", f"![Fig. 5: training curves]({figure})"]
    return "\n".join(lines)


def replace_block(text: str, block: str, where: str = "README.md") -> str:
    """``text`` with the part between :data:`START` and :data:`END` replaced by ``block``."""
    i, j = text.find(START), text.find(END)
    if i < 0 or j < i:
        raise GlanceError(f"{where}: the markers {START!r} and {END!r} are missing or out of order")
    return text[: i + len(START)] + "\n" + block + "\n" + text[j:]


def current_block(text: str, where: str = "README.md") -> str:
    """The block between the markers of ``text``."""
    i, j = text.find(START), text.find(END)
    if i < 0 or j < i:
        raise GlanceError(f"{where}: the markers {START!r} and {END!r} are missing or out of order")
    return text[i + len(START) : j].strip("\n")


def update_readme(preset: str = "quick", readme: str | Path | None = None) -> bool:
    """Rewrite the README's block from ``reference/<preset>/table1``; True when the README changed."""
    path = Path(readme) if readme is not None else project_root() / "README.md"
    text = path.read_text(encoding="utf-8")
    new = replace_block(text, render_glance(reference_table_dir(preset)), str(path))
    if new != text:
        atomic_write_text(path, new)
    return new != text
