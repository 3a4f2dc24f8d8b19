"""Reference artifacts: a preset's trained runs and their evaluations, kept in the repository under
``reference/<preset>/`` so that Table I, notebooks 07-09 and the transfer stage run in minutes on a fresh clone,
and so that trained runs outlast the machine that trained them.

Layout of a bundle (a plain folder; nothing in it is ever unpickled: checkpoints load with ``weights_only``)::

    reference/<preset>/bundle/MANIFEST.json
                                         format, preset, seeds, methods, the commit and date that made it, the
                                         archive's SHA-256 and every file in it with its SHA-256 and size
    reference/<preset>/bundle/runs.tar.xz
                                         runs/...: run folders as the run registry writes them (run.json,
                                         config.yaml, final.pt or encoder.pt, metrics.csv; no
                                         checkpoints, no tb/); eval/...: the evaluation cache of those runs
    reference/<preset>/table1/           the reference Table I the README shows (:func:`promote_table`)

:func:`pack_reference` makes a bundle from ``results/<preset>/``: every Table I method's finished run at the given
seeds, the runs they were trained from (the oracle, the encoders: found by the digests their run identity records)
and their cached evaluations. :func:`unpack_reference` verifies every file against the manifest, refuses to
replace a different file already in ``results/<preset>/``, copies the rest in (atomically), and checks that the
run registry of *this* code finds each run again (same configuration, same keys): a bundle made by other code is
reported, run by run, instead of being silently retrained.
"""

from __future__ import annotations

import copy
import datetime as _dt
import hashlib
import io
import json
import lzma
import shutil
import tarfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omcrl.config import Config, field_default, load_config, project_root, section_identity
from omcrl.eval.stage import EPISODES, eval_cache_root
from omcrl.eval.table1 import evaluate_grid
from omcrl.pipeline.released import pointer_path, read_kept, release
from omcrl.pipeline.storage import sha256
from omcrl.rl.methods import METHODS, TABLE1_METHODS, final_policy_path
from omcrl.runs import DIGEST_FIELDS, RUN_FILE, CorruptFile, read_identity, recorded_digest, run_key
from omcrl.scenes import SUITES, suite_of, suite_overrides
from omcrl.utils.io import atomic_save_torch, atomic_write_bytes, atomic_write_text, load_torch
from omcrl.utils.runtime import code_commit

FORMAT = 1
MANIFEST = "MANIFEST.json"
ARCHIVE = "runs.tar.xz"
# Besides its artifact and its record (run.json), what later stages read of a run; checkpoints
# (optimizer state, for resuming) and TensorBoard stay out.
RUN_EXTRAS = ("config.yaml", "metrics.csv")
ARTIFACTS = ("final.pt", "encoder.pt")
LIMIT_MB = 60.0


class ReferenceError(RuntimeError):
    """A reference bundle is missing, damaged, of another preset, or would replace different data; the message
    names the file."""


@dataclass(repr=False)
class ReferenceResult:
    """What :func:`pack_reference` or :func:`unpack_reference` did.

    Attributes
    ----------
    bundle : the bundle folder.
    manifest : the manifest (dict, as in ``MANIFEST.json``).
    copied, present : files written / already there with the same content (relative to the run root).
    found : ``{"method/seed<k>": run folder}`` that the run registry finds at the current configuration.
    not_found : ``"method/seed<k>"`` whose bundled run the registry does not find (made by other code or config).
    """

    bundle: Path
    manifest: dict[str, Any]
    copied: list[str] = field(default_factory=list)
    present: list[str] = field(default_factory=list)
    found: dict[str, Path] = field(default_factory=dict)
    not_found: list[str] = field(default_factory=list)

    @property
    def size_mb(self) -> float:
        """The files' size unpacked, MB."""
        return sum(f["bytes"] for f in self.manifest["files"].values()) / 1e6

    @property
    def archive_mb(self) -> float:
        """The archive's size in the repository, MB."""
        return self.manifest["archive"]["bytes"] / 1e6

    def __repr__(self) -> str:
        m = self.manifest
        lines = [
            f"bundle: {self.bundle} ({len(m['files'])} files, {self.size_mb:.1f} MB unpacked, {self.archive_mb:.1f} MB "
            f"archive; preset {m['preset']}, "
            f"seeds {m['seeds']}, made at commit {m['commit'][:12]} on {m['made']})"
        ]
        if self.copied or self.present:
            lines.append(f"copied {len(self.copied)} files, {len(self.present)} already there")
        if self.found:
            lines.append(f"the run registry finds {len(self.found)} runs: {', '.join(sorted(self.found))}")
        if self.not_found:
            lines.append(
                f"NOT found at this configuration (would be retrained): {', '.join(self.not_found)} - the bundle was "
                "made by other code or settings"
            )
        return "\n".join(lines)


def reference_table_dir(preset: str) -> Path:
    """``<checkout>/reference/<preset>/table1``: the reference Table I the README shows."""
    return project_root() / "reference" / preset / "table1"


def default_bundle(preset: str) -> Path:
    """``<checkout>/reference/<preset>/bundle``."""
    return project_root() / "reference" / preset / "bundle"


def _run_artifact(run_dir: Path) -> tuple[Path, str] | None:
    """(artifact, the digest its run recorded: :data:`omcrl.runs.DIGEST_FIELDS`) of a finished run folder, or None
    when it is not finished."""
    for name in ARTIFACTS:
        path = run_dir / name
        digest = recorded_digest(path) if path.is_file() else None
        if digest:
            return path, digest
    return None


def _digests_in(obj: Any) -> set[str]:
    """Every value of a ``*_digest`` key anywhere in a run identity (the upstream artifacts it was trained on)."""
    out: set[str] = set()
    if isinstance(obj, dict):
        for k, v in obj.items():
            if isinstance(v, str) and str(k).endswith("_digest") and v:
                out.add(v)
            else:
                out |= _digests_in(v)
    elif isinstance(obj, list):
        for v in obj:
            out |= _digests_in(v)
    return out


def _over_limit(size_mb: float, limit_mb: float, entries: dict[str, dict[str, Any]]) -> str:
    big = sorted(entries, key=lambda f: -entries[f]["bytes"])[:3]
    return f"the bundle's archive would be {size_mb:.1f} MB, over the limit of {limit_mb:g} MB; largest files: " + (
        ", ".join(f"{f} ({entries[f]['bytes'] / 1e6:.1f} MB)" for f in big)
    )


def _members_in_order(run_root: Path) -> Iterable[tuple[str, bytes]]:
    """``(name, content)`` of every file under ``run_root``'s ``runs/`` and ``eval/``, in the order the archive
    compresses best: xz's 64 MB window stores a repeat once, and a student's final.pt holds its frozen encoder's
    weights again, so each encoder goes right before the runs trained on it (then the other runs, then the
    evaluations)."""
    top = len(run_root.parts)
    files = [f for f in run_root.rglob("*") if f.is_file() and f.parts[top] in ("runs", "eval")]
    runs = {f.parent for f in files if f.parts[top] == "runs" and (f.parent / RUN_FILE).is_file()}
    encoders = {(_run_artifact(d) or (None, ""))[1] for d in runs if (d / "encoder.pt").is_file()}

    def order(f: Path) -> tuple:
        run = f.parent if f.parent in runs else None
        if run is None:
            return ("~", 2, str(f))
        own = (_run_artifact(run) or (None, ""))[1]
        ups = sorted(_digests_in((read_identity(run) or {}).get("identity", {})) & encoders)
        return (own, 0, str(f)) if own in encoders else ((ups or ["~"])[0], 1, str(f))

    return ((f.relative_to(run_root).as_posix(), f.read_bytes()) for f in sorted(files, key=order))


def _runs_with_upstream(run_root: Path, roots: list[Path]) -> list[Path]:
    """``roots`` and every run folder under ``run_root/runs`` whose artifact one of them was trained on
    (transitively)."""
    by_digest: dict[str, Path] = {}
    for rec in (run_root / "runs").glob("*/*/seed*/run.json"):
        art = _run_artifact(rec.parent)
        if art is not None:
            by_digest[art[1]] = rec.parent
    keep: list[Path] = []
    todo = list(roots)
    while todo:
        d = todo.pop()
        if d in keep:
            continue
        keep.append(d)
        ident = (read_identity(d) or {}).get("identity", {})
        todo += [by_digest[g] for g in _digests_in(ident) if g in by_digest and by_digest[g] not in keep]
    return sorted(keep)


# Tensors at least this large (weight matrices) are rounded to float16 precision in a bundle; small ones (biases,
# normaliser statistics, whose tiny values float16 would flush to zero) keep every bit.
ROUND_MIN_ELEMENTS = 4096


def _round_payload(obj: Any) -> Any:
    """``obj`` with every large float32 tensor rounded to the nearest float16 value (stored as float32 again)."""
    import torch

    if isinstance(obj, torch.Tensor):
        if obj.dtype == torch.float32 and obj.numel() >= ROUND_MIN_ELEMENTS:
            r = obj.to(torch.float16).to(torch.float32)
            return r if torch.isfinite(r).all() or not torch.isfinite(obj).all() else obj
        return obj
    if isinstance(obj, dict):
        return {k: _round_payload(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_round_payload(v) for v in obj)
    return obj


def _replace_digests(obj: Any, new: dict[str, str]) -> Any:
    if isinstance(obj, dict):
        return {
            k: (new.get(v, v) if isinstance(v, str) and str(k).endswith("_digest") else _replace_digests(v, new))
            for k, v in obj.items()
        }
    if isinstance(obj, list):
        return [_replace_digests(v, new) for v in obj]
    return obj


def _copy_runs(src_root: Path, dst_root: Path, run_dirs: list[Path], rounded: bool) -> dict[Path, Path]:
    """Copy ``run_dirs`` (a closed set: every upstream run is in it) from ``src_root`` to ``dst_root``, upstream
    first, with only the files later stages read. With ``rounded``, every artifact's large tensors are rounded to
    float16 precision; a run whose identity names a changed upstream artifact then gets the new digest and the key
    it gives (its folder moves with it), so the run registry finds each rounded run from the rounded files, and
    ``run.json`` records what it was rounded from. Returns ``{source folder: copied folder}``."""
    arts = {d: _run_artifact(d) for d in run_dirs}
    digest = {d: a[1] if a else "" for d, a in arts.items()}
    new_digest: dict[str, str] = {}
    out: dict[Path, Path] = {}
    pending = list(run_dirs)
    while pending:
        waiting = {digest[d] for d in pending}
        ready = [d for d in pending if not (_digests_in((read_identity(d) or {}).get("identity", {})) & waiting)]
        if not ready:
            raise ReferenceError(f"runs that name each other's artifacts: {', '.join(map(str, pending))}")
        for d in ready:
            pending.remove(d)
            records = {"run.json": dict(read_identity(d) or {})}
            rec = records["run.json"]
            if (
                run_key(rec.get("identity", {})) != rec.get("key")
                or d.parent.name != f"{rec.get('method')}-{rec.get('key')}"
            ):
                raise ReferenceError(f"{d / 'run.json'}: its key does not match its identity; refusing to bundle it")
            ident = _replace_digests(rec["identity"], new_digest)
            key = run_key(ident)
            target = dst_root / d.relative_to(src_root).parent.parent / f"{rec['method']}-{key}" / d.name
            target.mkdir(parents=True, exist_ok=True)
            for n in RUN_EXTRAS:
                if (d / n).is_file():
                    shutil.copyfile(d / n, target / n)
            if arts[d] is not None:
                path, old = arts[d]
                if rounded:
                    payload = _round_payload(load_torch(path, "artifact", ReferenceError))
                    new_digest[old] = atomic_save_torch(payload, target / path.name)
                else:
                    shutil.copyfile(path, target / path.name)
                    new_digest[old] = old
                record, fld = DIGEST_FIELDS[path.name]
                records[record][fld] = new_digest[old]
            rec.pop("checkpoint_digests", None)
            rec.update(key=key, identity=ident)
            if rounded:
                rec["reference"] = {"rounded_to": "float16", "min_elements": ROUND_MIN_ELEMENTS,
                                    "from_key": d.parent.name, "from_artifact_digest": digest[d]}  # fmt: skip
            for name, content in records.items():
                atomic_write_text(target / name, json.dumps(content, indent=1))
            out[d] = target
    return out


def _rounding_effect(before: Any, after: Any) -> dict[str, Any]:
    """Per-episode comparison of the same evaluation episodes flown by the original and the rounded policies."""
    key = ["method", "train_seed", "scene", "episode"]
    m = before.merge(after, on=key, suffixes=("", "_rounded"))
    sr = m.groupby(["method", "scene"])[["success", "success_rounded"]].mean().mul(100)
    diff = (sr["success_rounded"] - sr["success"]).round(1)
    return {
        "episodes": len(m),
        "changed_success": int((m["success"] != m["success_rounded"]).sum()),
        "changed_collision": int((m["collision"] != m["collision_rounded"]).sum()),
        "max_abs_sr_diff_points": float(diff.abs().max()) if len(diff) else 0.0,
        "sr_diff_points": {f"{a}/{b}": float(v) for (a, b), v in diff.items() if v != 0},
    }


def write_archive(path: Path, members: Iterable[tuple[str, bytes]]) -> dict[str, dict[str, Any]]:
    """Write a bundle's ``runs.tar.xz`` from ``(name, content)`` pairs, in their order, and return the manifest's
    ``files`` entries (SHA-256 and size of each). Members carry no dates or owners: the same runs give the same
    bytes."""
    entries: dict[str, dict[str, Any]] = {}
    with tarfile.open(path, "w:xz", preset=9) as tar:
        for rel, data in members:
            entries[rel] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
            info = tarfile.TarInfo(rel)
            info.size, info.mtime, info.mode = len(data), 0, 0o644
            tar.addfile(info, io.BytesIO(data))
    return entries


def pack_reference(
    cfg: Config,
    seeds: Sequence[int] | None = None,
    methods: Sequence[str] | None = None,
    out: str | Path | None = None,
    *,
    rounded: bool = True,
    limit_mb: float = LIMIT_MB,
    progress: bool = True,
) -> ReferenceResult:
    """Make a bundle (default ``reference/<preset>/bundle``) of the finished Table I runs of ``seeds`` (default
    ``cfg.seeds``) in ``cfg.run_root``, the runs they were trained from, and their evaluations. ``methods``: default
    every learned method of Table I but the controls (``MethodSpec.control``).

    With ``rounded`` (default) the artifacts' weight matrices are rounded to float16 precision (the archive then
    compresses to under half), the runs re-keyed to the rounded files (:func:`_copy_runs`), every learned method
    evaluated again from the rounded runs on Table I's episodes, and the effect of the rounding recorded in the
    manifest (``rounding``: episodes whose outcome changed, SR differences). Without it the files keep every bit
    and their cached evaluations come along.

    Raises ReferenceError when a method has no finished run at a seed, or when the archive would exceed
    ``limit_mb`` (naming the largest files); nothing is kept then. An existing bundle is replaced only after the
    new one is complete.
    """
    seeds = list(cfg.seeds if seeds is None else seeds)
    wrong = [m for m in methods or () if m not in METHODS or not METHODS[m].learned]
    if wrong:
        known = [m for m in METHODS if METHODS[m].learned]
        raise ReferenceError(f"methods: {wrong} are not learned methods (a bundle holds trained runs); known: {known}")
    # By default the paper's comparison: the controls (ours-random, ours-blind) are diagnostic rows of the grid, not
    # runs a user starts from; name them in ``methods`` to bundle them.
    default = [m for m in TABLE1_METHODS if not METHODS[m].control]
    methods = [m for m in (methods or default) if METHODS[m].learned]
    root = cfg.run_root
    finals, missing = [], []
    for m in methods:
        for s in seeds:
            p = final_policy_path(cfg.with_seed(s), m)
            (finals.append(p.parent) if p is not None else missing.append(f"{m}/seed{s}"))
    if missing:
        raise ReferenceError(
            f"no finished run under {root / 'runs'} for {', '.join(missing)}; train them first (notebooks 03-05 or "
            f"python -m omcrl train --method M --preset {cfg.preset} --seed K)"
        )
    dest = Path(out) if out is not None else default_bundle(cfg.preset)
    tmp = dest.with_name(dest.name + ".packing")
    shutil.rmtree(tmp, ignore_errors=True)
    stage = copy.deepcopy(cfg)
    stage.results_dir = str(tmp / "results")
    stage = stage.with_seed(cfg.seed)
    _copy_runs(root, stage.run_root, _runs_with_upstream(root, finals), rounded)
    ev_src = eval_cache_root(cfg)
    rounding: dict[str, Any] = {}
    for s in seeds:
        # Each cached evaluation is a run folder (<label>/seed<k>/<scene>-<key>/: run.json and episodes.csv).
        for f in sorted(p for p in ev_src.glob(f"*/seed{s}/*/*") if p.name in (RUN_FILE, EPISODES)):
            label = f.parent.parent.parent.name
            # A rounded policy is another checkpoint: its episodes are flown again below; planners' stay.
            if not rounded or not (label in METHODS and METHODS[label].learned):
                (stage.run_root / f.relative_to(root)).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(f, stage.run_root / f.relative_to(root))
    if rounded:
        before, _ = evaluate_grid(cfg, methods, seeds)
        after, _ = evaluate_grid(stage, methods, seeds, progress=progress)
        rounding = _rounding_effect(before, after)
    entries = write_archive(tmp / ARCHIVE, _members_in_order(stage.run_root))
    manifest = {
        "format": FORMAT,
        "preset": cfg.preset,
        "suite": config_suite(cfg),
        "overrides": config_overrides(cfg),
        "seeds": seeds,
        "methods": methods,
        "commit": code_commit(short=False),
        "made": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "rounded": "float16" if rounded else None,
        "rounding": rounding,
        "archive": {"name": ARCHIVE, "sha256": sha256(tmp / ARCHIVE), "bytes": (tmp / ARCHIVE).stat().st_size},
        "files": entries,
    }
    return _finish_bundle(tmp, dest, manifest, limit_mb)


def _finish_bundle(tmp: Path, dest: Path, manifest: dict[str, Any], limit_mb: float) -> ReferenceResult:
    """Check the archive ``tmp`` holds against ``limit_mb``, write the manifest beside it and put the folder at
    ``dest`` (an existing bundle there is replaced only now, when the new one is whole)."""
    size = manifest["archive"]["bytes"] / 1e6
    if size > limit_mb:
        shutil.rmtree(tmp)
        raise ReferenceError(_over_limit(size, limit_mb, manifest["files"]))
    shutil.rmtree(tmp / "results", ignore_errors=True)
    atomic_write_text(tmp / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    if dest.exists():
        shutil.rmtree(dest)
    tmp.rename(dest)
    return ReferenceResult(dest, manifest)


# Fields every part of a merged bundle must agree on: its runs were trained and flown alike.
_SAME_IN_PARTS = ("format", "preset", "suite", "overrides", "seeds", "rounded")


def merge_bundles(parts: Sequence[str | Path], out: str | Path, *, limit_mb: float = LIMIT_MB) -> ReferenceResult:
    """One bundle at ``out`` from bundles packed a few methods at a time (``pack_reference(methods=...)``).

    A grid outlasts the machine it runs on, and a bundle needs every method's weights at one seed: each method's
    part is packed (rounded, re-keyed, flown again) as soon as its run finishes, committed and retired to git
    history (:func:`retire_bundle`), and the parts are merged once the seed is whole. Rounding and re-keying are
    functions of the weights, so a run that two parts carry (the oracle, upstream of its students) is the same
    file in both and is stored once. Each part is verified first (a retired one is read from its git blob).

    The manifest is a packed one's, with ``methods`` the parts' together, ``rounding`` summed over them, and
    ``parts``: each part's folder name, methods, commit, date and rounding.

    Raises ReferenceError, before anything is written, when there are no parts, a part does not verify, parts
    differ in a field of :data:`_SAME_IN_PARTS` (named, with both values), two parts hold the same method or
    different content under one file name, or the archive would exceed ``limit_mb``.
    """
    if not parts:
        raise ReferenceError("merge: no bundle parts given")
    dest = Path(out)
    read = [(Path(b), *verify_reference(b)) for b in sorted(map(Path, parts))]
    first_b, first, _ = read[0]
    files: dict[str, bytes] = {}
    whence: dict[str, Path] = {}
    owner: dict[str, Path] = {}
    for b, m, contents in read:
        for fld in _SAME_IN_PARTS:
            if m.get(fld) != first.get(fld):
                raise ReferenceError(
                    f"{b / MANIFEST}: field {fld!r} is {m.get(fld)!r}, but {first_b / MANIFEST} has "
                    f"{first.get(fld)!r}; parts of one bundle must agree"
                )
        for meth in m.get("methods", []):
            if meth in owner:
                raise ReferenceError(f"method {meth!r} is in two parts: {owner[meth]} and {b}; merge one of them")
            owner[meth] = b
        for rel, data in contents.items():
            if rel in files and files[rel] != data:
                raise ReferenceError(f"{rel}: differs between {whence[rel]} and {b}; re-pack one of the parts")
            files.setdefault(rel, data)
            whence.setdefault(rel, b)
    tmp = dest.with_name(dest.name + ".packing")
    shutil.rmtree(tmp, ignore_errors=True)
    root = tmp / "results"
    for rel, data in files.items():
        atomic_write_bytes(root / rel, data)
    entries = write_archive(tmp / ARCHIVE, _members_in_order(root))
    effects = [m.get("rounding") or {} for _, m, _ in read]
    rounding: dict[str, Any] = {}
    if any(effects):
        rounding = {
            **{k: sum(int(e.get(k, 0)) for e in effects) for k in ("episodes", "changed_success", "changed_collision")},
            "max_abs_sr_diff_points": max(float(e.get("max_abs_sr_diff_points", 0.0)) for e in effects),
            "sr_diff_points": {k: v for e in effects for k, v in sorted(e.get("sr_diff_points", {}).items())},
        }
    order = {m: i for i, m in enumerate(METHODS)}
    manifest = {
        **{fld: first[fld] for fld in _SAME_IN_PARTS if fld in first},
        "methods": sorted(owner, key=lambda m: (order.get(m, len(order)), m)),
        "commit": code_commit(short=False),
        "made": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "rounding": rounding,
        "parts": [
            {
                "name": b.name,
                "methods": m.get("methods", []),
                "commit": m.get("commit"),
                "made": m.get("made"),
                "rounding": m.get("rounding") or {},
            }
            for b, m, _ in read
        ],
        "archive": {"name": ARCHIVE, "sha256": sha256(tmp / ARCHIVE), "bytes": (tmp / ARCHIVE).stat().st_size},
        "files": entries,
    }
    return _finish_bundle(tmp, dest, manifest, limit_mb)


def config_suite(cfg: Config) -> str:
    """The scene suite (a key of :data:`omcrl.scenes.SUITES`) whose box ``cfg`` trains in; ReferenceError for a
    training scene of no suite (such runs are not the paper's comparison)."""
    suite = suite_of(cfg.env.scene)
    if suite is not None:
        return suite
    raise ReferenceError(f"env.scene {cfg.env.scene!r} is the training scene of no suite {dict(SUITES)}")


def config_overrides(cfg: Config) -> list[str]:
    """The ``--set`` overrides, beyond its suite's, under which ``cfg``'s runs are found: every identity field of
    the sections runs read (env, data, pretrain, rl) where ``cfg`` differs from its preset (so a bundle trained at
    an earlier budget is still found after the preset changed)."""
    base = load_config(cfg.preset).with_suite(config_suite(cfg))
    out = []
    for sec in ("env", "data", "pretrain", "rl"):
        section = getattr(cfg, sec)
        mine, theirs = section_identity(section), section_identity(getattr(base, sec))
        for name in dict.fromkeys([*mine, *theirs]):
            if mine.get(name) != theirs.get(name):
                value = mine[name] if name in mine else field_default(section, name)  # identity values are plain
                out.append(f"{sec}.{name}={json.dumps(value)}")
    return out


def bundle_suite(manifest: dict[str, Any]) -> str:
    """The suite a bundle's runs were trained and evaluated in: its manifest's ``suite``; bundles made before the
    field existed hold v1 runs."""
    suite = manifest.get("suite", "v1")
    if suite not in SUITES:
        raise ReferenceError(f"{MANIFEST}: field 'suite' is {suite!r}, expected one of {list(SUITES)}")
    return suite


def bundle_overrides(preset: str, bundle: str | Path | None = None) -> list[str]:
    """The ``--set`` overrides under which a bundle's runs are found: :func:`omcrl.scenes.suite_overrides` of its
    suite, the manifest's own overrides, and its training seeds (``seed`` = the first, ``seeds`` = all: the v2
    bundle holds seed 2, and a preset's default seed 0 would train runs the bundle does not have).
    ``reproduce.sh --from-reference`` passes them to the notebooks it runs."""
    b = Path(bundle) if bundle is not None else default_bundle(preset)
    m = read_manifest(b, preset)
    seeds = m.get("seeds")
    if not isinstance(seeds, list) or not seeds or not all(isinstance(v, int) and v >= 0 for v in seeds):
        raise ReferenceError(f"{b / MANIFEST}: field 'seeds' is {seeds!r}, expected a non-empty list of integers >= 0")
    seed_sets = [f"seed={seeds[0]}", f"seeds=[{', '.join(map(str, seeds))}]"]
    return [*suite_overrides(bundle_suite(m)), *manifest_overrides(m), *seed_sets]


def manifest_overrides(manifest: dict[str, Any]) -> list[str]:
    """The manifest's ``overrides`` (a list of ``'section.field=value'``; none in bundles made before the field)."""
    got = manifest.get("overrides", [])
    if not isinstance(got, list) or not all(isinstance(o, str) and "=" in o for o in got):
        raise ReferenceError(f"{MANIFEST}: field 'overrides' is {got!r}, expected a list of 'section.field=value'")
    return got


def read_manifest(bundle: str | Path, preset: str | None = None) -> dict[str, Any]:
    """The manifest of a bundle folder, checked for its form (and its preset when given)."""
    path = Path(bundle) / MANIFEST
    if not path.is_file():
        raise ReferenceError(
            f"{path}: no reference manifest there (expected a bundle folder: `python -m omcrl reference --pack`)"
        )
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ReferenceError(f"{path}: not a readable manifest ({e})") from None
    if not isinstance(m, dict) or not isinstance(m.get("files"), dict):
        raise ReferenceError(
            f"{path}: field 'files' missing; expected a manifest made by `python -m omcrl reference --pack`"
        )
    if m.get("format") != FORMAT:
        raise ReferenceError(f"{path}: field 'format' is {m.get('format')!r}, expected {FORMAT}")
    if preset is not None and m.get("preset") != preset:
        raise ReferenceError(f"{path}: field 'preset' is {m.get('preset')!r}, expected {preset!r}")
    arch = m.get("archive")
    if not isinstance(arch, dict) or arch.get("name") != ARCHIVE or not arch.get("sha256"):
        raise ReferenceError(
            f"{path}: field 'archive' is {arch!r}, expected {{'name': {ARCHIVE!r}, 'sha256', 'bytes'}}"
        )
    for rel in m["files"]:
        p = Path(rel)
        if p.is_absolute() or ".." in p.parts:
            raise ReferenceError(f"{path}: file {rel!r} leaves the bundle; refusing it")
    return m


def verify_reference(bundle: str | Path, preset: str | None = None) -> tuple[dict[str, Any], dict[str, bytes]]:
    """Check a bundle against its manifest and read it: the archive's SHA-256, then every file in it (listed,
    a plain file, its size and SHA-256), and no listed file missing. Returns (manifest, {path: content}).

    Nothing is extracted to disk: members are read into memory, so a crafted archive cannot write anywhere.
    Raises ReferenceError naming the first thing that is wrong.
    """
    b = Path(bundle)
    m = read_manifest(b, preset)
    arch = b / ARCHIVE
    # A retired bundle's archive lives in git history (retire_bundle): read from the blob its pointer names.
    try:
        data = read_kept(arch, "this bundle cannot be read here (a full clone has it)")
    except CorruptFile as e:
        raise ReferenceError(str(e)) from None
    if data is None:
        where = "its git blob is not in this repository" if pointer_path(arch).is_file() else "missing"
        raise ReferenceError(f"{arch}: listed in {b / MANIFEST} but {where}")
    if len(data) != m["archive"].get("bytes") or hashlib.sha256(data).hexdigest() != m["archive"]["sha256"]:
        raise ReferenceError(f"{arch}: does not match its SHA-256 in {b / MANIFEST} (damaged or changed)")
    out: dict[str, bytes] = {}
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:xz") as tar:
            for member in tar:
                name = member.name
                where = f"{arch}: member {name!r}"
                if name not in m["files"]:
                    raise ReferenceError(f"{where} is not in the manifest; refusing the bundle")
                if not member.isfile():
                    raise ReferenceError(f"{where} is not a plain file; refusing the bundle")
                fh = tar.extractfile(member)
                data = fh.read() if fh is not None else b""
                want = m["files"][name]
                if len(data) != want["bytes"] or hashlib.sha256(data).hexdigest() != want["sha256"]:
                    raise ReferenceError(f"{where} does not match its SHA-256 in {b / MANIFEST} (damaged or changed)")
                out[name] = data
    except (tarfile.TarError, EOFError, lzma.LZMAError) as e:
        raise ReferenceError(f"{arch}: not a readable xz tar archive ({e})") from None
    lacking = sorted(set(m["files"]) - set(out))
    if lacking:
        raise ReferenceError(f"{arch}: {lacking[0]} is listed in {b / MANIFEST} but not in the archive")
    return m, out


def retire_bundle(bundle: str | Path) -> Path:
    """Take a committed bundle's archive out of the checkout, leaving ``runs.tar.xz.git.json`` (its git blob) beside
    the manifest: the bundle stays verifiable and unpackable from a full clone (:func:`verify_reference` reads the
    blob), and ``reference/`` keeps its 60 MB for the bundles in use. Returns the pointer written.

    Raises ReferenceError when the bundle does not verify, or its archive is not in a commit yet (commit it first:
    the pointer must name a blob that git history keeps).
    """
    b = Path(bundle)
    verify_reference(b)  # whole before anything changes
    pointer = release(b / ARCHIVE)
    if pointer is None:
        raise ReferenceError(f"{b / ARCHIVE}: not in a commit of this repository; commit the bundle before retiring it")
    return pointer


def registered_runs(cfg: Config, manifest: dict[str, Any]) -> tuple[dict[str, Path], list[str]]:
    """Which of a bundle's runs the run registry finds at ``cfg`` (this code, this configuration):
    ``({"method/seed<k>": folder}, [not found])``."""
    found, missing = {}, []
    for m in manifest.get("methods", []):
        for s in manifest.get("seeds", []):
            p = final_policy_path(cfg.with_seed(int(s)), m)
            bundled = p is not None and p.relative_to(cfg.run_root).as_posix() in manifest["files"]
            (found.__setitem__(f"{m}/seed{s}", p.parent) if bundled else missing.append(f"{m}/seed{s}"))
    return found, missing


def unpack_reference(cfg: Config, bundle: str | Path | None = None) -> ReferenceResult:
    """Verify a bundle (default ``reference/<cfg.preset>``) and copy it into ``cfg.run_root``.

    Every file is checked before anything is copied; a file already in the run root with other content is never
    replaced (ReferenceError naming it: move it away or use another ``results_dir``). Afterwards the run
    registry is asked for each bundled run at this configuration (:func:`registered_runs`).
    """
    b = Path(bundle) if bundle is not None else default_bundle(cfg.preset)
    m, contents = verify_reference(b, cfg.preset)
    cfg = cfg.with_suite(bundle_suite(m)).with_overrides(manifest_overrides(m))  # as its runs were trained
    root = cfg.run_root
    plan, present = [], []
    for rel, want in sorted(m["files"].items()):
        target = root / rel
        if target.exists():
            if target.is_file() and sha256(target) == want["sha256"]:
                present.append(rel)
                continue
            raise ReferenceError(
                f"{target}: exists with other content than the bundle's {rel}; not replacing it (move it away, "
                "or unpack into another results_dir)"
            )
        plan.append(rel)
    for rel in plan:
        atomic_write_bytes(root / rel, contents[rel])
    found, missing = registered_runs(cfg, m)
    return ReferenceResult(b, m, copied=plan, present=present, found=found, not_found=missing)


def promote_table(cfg: Config) -> Path:
    """Make ``results/<preset>/tables/`` (``table1.csv``, ``table1_summary.json``, ``table1.md``) the reference Table
    I, ``reference/<preset>/table1/``, which the README shows (:mod:`omcrl.pipeline.glance`); returns that folder."""
    src, dest = cfg.run_root / "tables", reference_table_dir(cfg.preset)
    names = ("table1.csv", "table1_summary.json", "table1.md")
    for n in names[:2]:
        if not (src / n).is_file():
            raise ReferenceError(f"{src / n}: missing; run the tables first (notebook 07 or python -m omcrl tables)")
    for n in names:
        if (src / n).is_file():
            atomic_write_bytes(dest / n, (src / n).read_bytes())
    return dest


def reference_stage(
    cfg: Config,
    *,
    pack: bool = False,
    source: str | None = None,
    with_table: bool = False,
    exact: bool = False,
    methods: Sequence[str] | None = None,
    merge: str | None = None,
    retire: bool = False,
) -> ReferenceResult:
    """CLI stage ``reference``: unpack the bundle (``reference/<preset>/bundle``, or ``source``) into the run root,
    verified; with ``pack``, make the bundle from the run root's finished runs of ``methods`` (default: every learned
    Table I method) at ``cfg.seeds`` instead (and with ``with_table`` make its Table I the reference one); with
    ``merge`` (a folder of bundle parts), merge every bundle in it into ``source`` (:func:`merge_bundles`); with
    ``retire``, retire the committed bundle ``source`` to git history (:func:`retire_bundle`)."""
    if sum(map(bool, (pack, merge, retire))) > 1:
        raise ReferenceError("reference: choose one of --pack, --merge and --retire")
    dest = Path(source) if source is not None else default_bundle(cfg.preset)
    if merge is not None:
        parts = sorted(p.parent for p in Path(merge).glob(f"*/{MANIFEST}"))
        if not parts:
            raise ReferenceError(f"{merge}: no bundle folders (each with {MANIFEST}) in it to merge")
        return merge_bundles(parts, dest)
    if retire:
        retire_bundle(dest)
        return ReferenceResult(dest, read_manifest(dest))
    if pack:
        res = pack_reference(cfg, methods=methods, out=source, rounded=not exact)
        if with_table:
            promote_table(cfg)
        return res
    return unpack_reference(cfg, source)
