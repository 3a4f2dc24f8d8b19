"""Ablation tables (paper VI-C): a sweep's evaluation episodes aggregated per variant and scene, with CIs.

:func:`write_ablation` writes ``tables/ablation_<grid>.{csv,md,tex}`` in Table I's layout (variants as rows,
mean ± CI half-width over seeds and episodes); the ``sequential`` grid is also written as ``table2.*`` (paper
Table II) and the ``decay`` grid as ``table3.*`` (Table III), each with ``<table>_vs_paper.{csv,md}``: the paper's
values (``paper_ablations.csv`` in this package) beside the kit's.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from omcrl.eval.metrics import episode_values
from omcrl.eval.stage import to_markdown
from omcrl.eval.stats import BOUNDED, aggregate, cell_rng, compare_sr
from omcrl.eval.table1 import _latex, _markdown, table1_frames, vs_paper, vs_paper_markdown
from omcrl.eval.verdicts import cell, holm_verdicts, judge
from omcrl.scenes import is_stress, is_unseen
from omcrl.utils.io import atomic_write_text

PAPER_TABLES = {"sequential": "table2", "decay": "table3"}
PAPER_ABLATIONS = Path(__file__).with_name("paper_ablations.csv")
# The paper's caption of each table, for the files that set its values beside the kit's.
PAPER_CAPTIONS = {
    "sequential": "Table II of the OMC-RL paper (sequential input; evaluation scenes, Unity)",
    "decay": "Table III of the OMC-RL paper (decay strategies; its Ours, Ours-exp, Ours-fixed are linear, exp, fixed)",
}


def paper_ablations(grid: str | None = None) -> pd.DataFrame:
    """The paper's Tables II and III (long: ``grid, label, scene, NE OS SR SPL CR TTS``), labels as in the grids
    of :mod:`omcrl.pipeline.grids`; ``grid``: only that grid's rows (none for a grid the paper gives no numbers)."""
    df = pd.read_csv(PAPER_ABLATIONS, comment="#")
    return df if grid is None else df[df["grid"] == grid].reset_index(drop=True)


def ablation_table(episodes: pd.DataFrame, reps: int = 2000, order: Sequence[str] = ()) -> pd.DataFrame:
    """Metrics with 95 % CIs per variant (``label``) and scene: :func:`omcrl.eval.stats.aggregate` by
    (label, scene), index renamed (method, scene) so Table I's writers apply. ``order``: the variants' labels in
    the grid's order (the paper's: linear, exp, fixed), which the rows then follow; labels not in it come after."""
    ep = episodes.drop(columns=["method"]).rename(columns={"label": "method"})
    table = aggregate(ep, ("method", "scene"), reps=reps)
    rank = {label: i for i, label in enumerate(order)}
    rows = sorted(range(len(table)), key=lambda i: (rank.get(table.index[i][0], len(rank)), i))
    return table.iloc[rows]


def write_ablation(
    episodes: pd.DataFrame, directory: str | Path, grid: str, reps: int = 2000, order: Sequence[str] = ()
) -> dict[str, Path]:
    """Write the ablation table of ``grid`` (and its paper-table copy); returns the paths by suffix. ``order``:
    :func:`ablation_table`'s."""

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    table = ablation_table(episodes, reps, order)
    long, wide = table1_frames(table)
    seeds = int(table["seeds"].max()) if len(table) else 0
    note = (
        f"Ablation `{grid}`: mean ± half-width of the 95% CI over {seeds} training seed(s) and the evaluation "
        "episodes. NE m, OS/SR/CR %, SPL 0-1, TTS steps. Bold: best variant.\n\n"
    )
    paths: dict[str, Path] = {}
    if grid in PAPER_TABLES:
        # The paper's values where it prints numbers (Tables II and III), the kit's mean [95 % CI] beside each.
        vp = vs_paper(table, paper_ablations(grid).drop(columns="grid").rename(columns={"label": "method"}))
        name = f"{PAPER_TABLES[grid]}_vs_paper"
        for suffix, text in (("csv", vp.to_csv(index=False)), ("md", vs_paper_markdown(vp, PAPER_CAPTIONS[grid]))):
            paths[f"{name}.{suffix}"] = d / f"{name}.{suffix}"
            atomic_write_text(paths[f"{name}.{suffix}"], text)
    for name in (f"ablation_{grid}", PAPER_TABLES.get(grid)):
        if name is None:
            continue
        for suffix, text in (
            ("csv", long.to_csv(index=False)),
            ("md", note + _markdown(wide, {})),
            ("tex", _latex(wide, {})),
        ):
            path = d / f"{name}.{suffix}"
            atomic_write_text(path, text)
            paths[f"{name}.{suffix}"] = path
    return paths


# The paper's six ablation findings (VI-C) as orderings "a > b" in SR between variants (labels of
# :data:`omcrl.pipeline.grids.GRIDS`), checked in every evaluation scene, as the paper reports ablations there.
ABLATION_CLAIMS: tuple[tuple[str, str, str, str], ...] = (
    *(("1 masking: rho = 0.5 is best", "mask-prob", "rho=0.5", f"rho={r}") for r in (0.1, 0.3, 0.7, 0.9)),
    ("2 sequential input does not help CURL", "sequential", "CURL", "CURL-cons"),
    ("3 a second Transformer hurts", "dual-transformer", "Ours", "Ours-dualT"),
    ("4 phi helps ours and CURL; ours stays ahead", "projection", "Ours", "Ours w/o phi"),
    ("4 phi helps ours and CURL; ours stays ahead", "projection", "CURL w/ phi", "CURL"),
    ("4 phi helps ours and CURL; ours stays ahead", "projection", "Ours w/o phi", "CURL"),
    ("4 phi helps ours and CURL; ours stays ahead", "projection", "Ours", "CURL w/ phi"),
    ("5 the oracle teacher helps ours and NPE", "oracle-teacher", "Ours", "Ours w/o OT"),
    ("5 the oracle teacher helps ours and NPE", "oracle-teacher", "NPE w/ OT", "NPE"),
    ("5 the oracle teacher helps ours and NPE", "oracle-teacher", "Ours w/o OT", "NPE w/ OT"),
    ("6 linear decay beats exponential and fixed", "decay", "linear", "exp"),
    ("6 linear decay beats exponential and fixed", "decay", "linear", "fixed"),
)


def ablation_findings(
    episodes: dict[str, pd.DataFrame], scenes: list[str] | None = None, reps: int = 2000, seed: int = 0
) -> pd.DataFrame:
    """Does each ordering of :data:`ABLATION_CLAIMS` hold here? Judged as Table I's ledger is
    (:mod:`omcrl.eval.verdicts`): the two variants paired layout by layout and seed by seed, training seeds and
    layouts crossed, Holm–Bonferroni over every check in the paper's unseen scenes (one family) and, apart, over
    the stress-test checks.

    Parameters
    ----------
    episodes : ``{grid: sweep episodes}`` (``SweepResult.episodes``, with ``label``); grids not given are skipped.
    scenes : scenes to check (default: every evaluated scene but ``box``, the training scene).

    Returns
    -------
    DataFrame ``finding, grid, claim, scene, diff, lo, hi, p, p_holm, seeds, verdict``: the SR difference a − b in
    percentage points with its 95 % CI, and ``holds`` / ``reversed`` (Holm-adjusted p < 0.05, by its sign),
    ``undecided``, or ``one seed`` (a variant of one training seed: shown, not judged).
    """
    rows = []
    for finding, grid, a, b in ABLATION_CLAIMS:
        ep = episodes.get(grid)
        if ep is None or ep.empty or not {a, b} <= set(ep["label"]):
            continue
        sub = ep[ep["label"].isin([a, b])].drop(columns=["method"]).rename(columns={"label": "method"})
        values = episode_values(sub)
        for sc in scenes or [s for s in dict.fromkeys(sub["scene"]) if is_unseen(s)]:
            terms = [cell(sub, values, "SR", a, sc, 1.0), cell(sub, values, "SR", b, sc, -1.0)]
            rows.append({"finding": finding, "grid": grid, "claim": f"{a} > {b}", "scene": sc,
                         "family": "stress" if is_stress(sc) else "unseen",
                         **judge(terms, [True, True], reps, cell_rng(seed, finding, grid, sc),
                                 BOUNDED["SR"])})  # fmt: skip
    cols = ["finding", "grid", "claim", "scene", "diff", "lo", "hi", "p", "p_holm", "seeds", "verdict"]
    if not rows:
        return pd.DataFrame(columns=cols)
    return holm_verdicts(pd.DataFrame(rows), "family").rename(columns={"estimate": "diff"})[cols]


def _verdict(g: pd.DataFrame) -> tuple[int, int, int, str]:
    n = g["verdict"].value_counts()
    h, r, u = (int(n.get(k, 0)) for k in ("holds", "reversed", "undecided"))
    judged = h + r + u
    if judged == 0:
        return h, r, u, "one seed" if int(n.get("one seed", 0)) else "not run"
    verdict = "holds" if h == judged else "does not hold" if r and not h else "undecided" if u == judged else "partly"
    return h, r, u, verdict


# The columns of :func:`findings_summary` that the pages show (the rest are its stress counts as numbers).
SUMMARY_COLUMNS = ["finding", "checks", "holds", "reversed", "undecided", "verdict", "stress", "stress verdict"]


def findings_summary(findings: pd.DataFrame) -> pd.DataFrame:
    """One line per finding: how many (claim, scene) checks in the paper's unseen scenes hold, are reversed or
    undecided, and a verdict ``holds`` (every check holds), ``does not hold`` (any reversed, none holds),
    ``partly`` or ``undecided``.

    Stress-test scenes (furniture-v0's unseen room) are not the paper's suite, so they do not enter the verdict;
    ``stress`` counts their checks apart, as ``held / reversed / undecided`` ("–" when none was evaluated), and
    ``stress verdict`` is the same rule applied to them alone. A finding checked only in stress scenes has the
    verdict ``not checked``. The stress counts are also columns of their own (``stress holds``, ``stress reversed``,
    ``stress undecided``: ints, 0 when none was evaluated), so a reader of the frame need not parse the text;
    :data:`SUMMARY_COLUMNS` are the ones a page shows.
    """
    cols = [*SUMMARY_COLUMNS, "stress holds", "stress reversed", "stress undecided"]
    out = []
    for finding, g in findings.assign(_stress=findings["scene"].map(is_stress)).groupby("finding", sort=False):
        main, st = g[~g["_stress"]], g[g["_stress"]]
        h, r, u, verdict = _verdict(main) if len(main) else (0, 0, 0, "not checked")
        sh, sr_, su, sv = _verdict(st) if len(st) else (0, 0, 0, "–")
        out.append({"finding": finding, "checks": len(main), "holds": h, "reversed": r, "undecided": u,
                    "verdict": verdict, "stress": f"{sh} / {sr_} / {su}" if len(st) else "–",
                    "stress verdict": sv, "stress holds": sh, "stress reversed": sr_,
                    "stress undecided": su})  # fmt: skip
    return pd.DataFrame(out, columns=cols)


def write_findings(
    episodes: dict[str, pd.DataFrame],
    directory: str | Path,
    reps: int = 2000,
    name: str = "ablation_findings",
    intro: str = "",
) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Path]]:
    """:func:`ablation_findings` and :func:`findings_summary` of ``episodes``, written as ``<name>.csv`` (every
    check) and ``<name>.md`` (``intro``, the summary, then the checks)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    f = ablation_findings(episodes, reps=reps)
    s = findings_summary(f)
    paths = {"csv": d / f"{name}.csv", "md": d / f"{name}.md"}
    atomic_write_text(paths["csv"], f.to_csv(index=False))

    ci = [f"{r.diff:+.1f} [{r.lo:+.1f}, {r.hi:+.1f}]" for r in f.itertuples()]
    detail = f.assign(**{"SR a − b (pp) [95 % CI]": ci})[
        ["finding", "claim", "scene", "SR a − b (pp) [95 % CI]", "verdict"]
    ]
    text = (
        (f"{intro}\n\n" if intro else "")
        + "The paper's ablation findings (VI-C), checked in SR in every evaluation scene (variants paired layout by "
        "layout, training seeds and layouts crossed, Holm–Bonferroni over the unseen-scene checks and, apart, over "
        "the stress-test checks; a variant of one training seed is shown, not judged): the verdict counts the "
        "paper's unseen scenes; stress-test scenes are counted apart (held / reversed / undecided).\n\n"
        + to_markdown(s[SUMMARY_COLUMNS].set_index("finding"), "finding")
        + "\n"
        + to_markdown(detail.set_index("finding"), "finding")
    )
    atomic_write_text(paths["md"], text)
    return f, s, paths


# The zero-shot target of the generalisation issue: SR at least this (%) in every unseen scene.
ZERO_SHOT_TARGET = 50.0


def remedy_verdicts(
    episodes: pd.DataFrame, reference: str = "default", target: float = ZERO_SHOT_TARGET, reps: int = 2000
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """How each remedy of a ``remedy-*`` sweep (:data:`omcrl.pipeline.sweep.REMEDY_VARIANTS`) changes the zero-shot SR.

    Parameters
    ----------
    episodes : a sweep's evaluation episodes (``label`` = variant, ``scene``, ``train_seed``, ``success`` ...).
    reference : the label of the unchanged student.
    target : SR (%) the issue asks for in every unseen scene.

    Returns
    -------
    (checks, summary). ``checks``: one row per variant and scene, ``label, scene, seeds, SR, SR_lo, SR_hi``
    (% with the 95 % CI of :func:`omcrl.eval.stats.aggregate`: seeds and layouts crossed) and, for the remedies,
    ``diff, diff_lo, diff_hi`` (variant − reference in percentage points) and ``change`` (``better`` / ``worse`` where
    the CI excludes 0, else ``unresolved``). ``summary``: one row per variant, its lowest SR over the unseen scenes
    (every scene but box), ``target``: ``met`` (every unseen SR ≥ target), ``met within CI`` (every upper bound ≥
    target), or ``not met``, and ``seeds meeting it``: ``k/n``, the training seeds whose own SR reaches the target
    in every unseen scene (with two or three seeds a wide CI can reach the target while no single seed does).
    """

    ep = episodes.drop(columns=["method"], errors="ignore").rename(columns={"label": "method"})
    if reference not in set(ep["method"]):
        raise KeyError(f"remedy_verdicts: no episodes of the reference variant {reference!r}")
    agg = aggregate(ep, ("method", "scene"), reps=reps)
    sig = compare_sr(ep, reference=reference, reps=reps)
    rows = []
    for (label, scene), r in agg.iterrows():
        row = {"label": label, "scene": scene, "seeds": int(r["seeds"]), "SR": r["SR"], "SR_lo": r["SR_lo"],
               "SR_hi": r["SR_hi"]}  # fmt: skip
        d = sig[(sig.scene == scene) & (sig.method == label)]
        if len(d):
            # compare_sr gives reference − variant; a remedy is read as variant − reference.
            diff, lo, hi = (0.0 - float(d[c].iloc[0]) for c in ("diff", "hi", "lo"))
            row.update(diff=diff, diff_lo=lo, diff_hi=hi,
                       change="better" if lo > 0 else "worse" if hi < 0 else "unresolved")  # fmt: skip
        rows.append(row)
    checks = pd.DataFrame(rows)
    unseen = ep[ep.scene.map(is_unseen)]
    # SR (%) per variant, training seed and scene; a seed meets the target only if all its unseen scenes do.
    per_seed = unseen.groupby(["method", "train_seed", "scene"])["success"].mean().mul(100.0)
    seed_ok = per_seed.ge(target).groupby(level=["method", "train_seed"]).all()
    summary = []
    for label, g in checks[checks.scene.map(is_unseen)].groupby("label", sort=False):
        met = "met" if (g.SR >= target).all() else "met within CI" if (g.SR_hi >= target).all() else "not met"
        worst = g.loc[g.SR.idxmin()]
        ok = seed_ok.loc[label]
        summary.append({"label": label, "seeds": int(g.seeds.min()), "lowest unseen SR": float(worst.SR),
                        "in": worst.scene, "target": met,
                        "seeds meeting it": f"{int(ok.sum())}/{len(ok)}"})  # fmt: skip
    columns = ["label", "seeds", "lowest unseen SR", "in", "target", "seeds meeting it"]
    return checks, pd.DataFrame(summary, columns=columns)


def write_remedies(
    episodes: pd.DataFrame, directory: str | Path, grid: str, reps: int = 2000
) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, Path]]:
    """:func:`remedy_verdicts` written as ``remedy_<grid>.csv`` (every check) and ``remedy_<grid>.md``."""

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    checks, summary = remedy_verdicts(episodes, reps=reps)
    paths = {"csv": d / f"remedy_{grid}.csv", "md": d / f"remedy_{grid}.md"}
    atomic_write_text(paths["csv"], checks.to_csv(index=False))

    def ci(v: float, lo: float, hi: float, sign: str = "") -> str:
        return "" if pd.isna(v) else f"{v:{sign}.0f} [{lo:{sign}.0f}, {hi:{sign}.0f}]"

    table = checks.assign(
        **{
            "SR % [95 % CI]": [ci(r.SR, r.SR_lo, r.SR_hi) for r in checks.itertuples()],
            "vs default (pp)": [
                ci(getattr(r, "diff", float("nan")), getattr(r, "diff_lo", 0), getattr(r, "diff_hi", 0), "+")
                for r in checks.itertuples()
            ],
        }
    )
    wide = table.pivot(index="label", columns="scene", values="SR % [95 % CI]").loc[list(dict.fromkeys(checks.label))]
    wide = wide[list(dict.fromkeys(checks.scene))]
    diffs = table[table["vs default (pp)"] != ""]
    text = (
        f"Remedies (`{grid}`): the guided student with one change each, trained in box only, SR over "
        f"{int(checks.seeds.max())} seed(s); target ≥ {ZERO_SHOT_TARGET:.0f} % in every unseen scene.\n\n"
        + to_markdown(wide, "variant")
        + "\n"
        + to_markdown(summary.set_index("label"), "variant")
    )
    if len(diffs):
        dw = diffs.pivot(index="label", columns="scene", values="vs default (pp)")
        dw = dw.loc[list(dict.fromkeys(diffs.label)), list(dict.fromkeys(diffs.scene))]
        text += "\nChange against the default (variant − default, pp, 95 % CI):\n\n" + to_markdown(dw, "variant")
    atomic_write_text(paths["md"], text)
    return checks, summary, paths


def precision_table(episodes: pd.DataFrame, reps: int = 2000) -> pd.DataFrame:
    """bf16 against fp32 per method and scene, from the ``precision`` sweep (labels ``<method> fp32|bf16``).

    Returns one row per method and scene: ``method, scene, seeds, SR_fp32, SR_bf16`` (%) and ``diff, lo, hi``
    (bf16 − fp32 in percentage points, 95 % CI of the paired difference, :func:`omcrl.eval.stats.compare_sr`),
    ``resolved`` (the CI excludes 0).
    """

    ep = episodes.drop(columns=["method"], errors="ignore").rename(columns={"label": "method"})
    agg = aggregate(ep, ("method", "scene"), reps=reps)
    rows = []
    for base in dict.fromkeys(m.rsplit(" ", 1)[0] for m in ep["method"] if m.endswith((" fp32", " bf16"))):
        a, b = f"{base} fp32", f"{base} bf16"
        if not {a, b} <= set(ep["method"]):
            continue
        sig = compare_sr(ep[ep.method.isin([a, b])], reference=b, reps=reps)
        for r in sig.itertuples():
            rows.append({"method": base, "scene": r.scene, "seeds": int(agg.loc[(a, r.scene), "seeds"]),
                         "SR_fp32": agg.loc[(a, r.scene), "SR"], "SR_bf16": agg.loc[(b, r.scene), "SR"],
                         "diff": r.diff, "lo": r.lo, "hi": r.hi, "resolved": bool(r.lo > 0 or r.hi < 0)})  # fmt: skip
    return pd.DataFrame(
        rows, columns=["method", "scene", "seeds", "SR_fp32", "SR_bf16", "diff", "lo", "hi", "resolved"]
    )


def write_precision(
    episodes: pd.DataFrame, directory: str | Path, reps: int = 2000
) -> tuple[pd.DataFrame, dict[str, Path]]:
    """:func:`precision_table` as ``precision.csv`` and ``precision.md`` under ``directory``."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    table = precision_table(episodes, reps=reps)
    paths = {"csv": d / "precision.csv", "md": d / "precision.md"}
    atomic_write_text(paths["csv"], table.to_csv(index=False))
    lines = [
        "bf16 − fp32 success rate (pp) per method and scene, 95 % CI of the paired difference (training seeds and "
        "layouts crossed); resolved where the CI excludes 0.",
        "",
        "| method | scene | seeds | SR fp32 % | SR bf16 % | bf16 − fp32 pp [95 % CI] | resolved |",
        "|---|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r.method} | {r.scene} | {r.seeds} | {r.SR_fp32:.0f} | {r.SR_bf16:.0f} | {r.diff:+.0f} "
        f"[{r.lo:+.0f}, {r.hi:+.0f}] | {'yes' if r.resolved else 'no'} |"
        for r in table.itertuples()
    ]
    n_res = int(table.resolved.sum()) if len(table) else 0
    lines += ["", f"{n_res} of {len(table)} differences resolved."]
    atomic_write_text(paths["md"], "\n".join(lines) + "\n")
    return table, paths
