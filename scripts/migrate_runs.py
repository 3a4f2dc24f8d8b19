"""Migrate runs and bundles written before three changes of issue 43 (one way to finish a run; the oracle's guidance in
its own config section; evaluation caches as runs).

    python scripts/migrate_runs.py PATH [PATH ...]

Until then a finished pretraining wrote ``done.json`` beside its ``run.json`` (the encoder's digest, the iterations,
the final loss and the dataset it was made of); now :meth:`omcrl.runs.Run.finish` records the same fields in
``run.json``, as every RL run does, and ``done.json`` is no longer read. The keys, the encoders and every other file
stay as they are. A PATH is any of:

* a results folder (``results/quick``) or any folder holding run folders: each ``done.json`` beside a pretraining
  ``run.json`` is merged into it and removed (the encoder, when present, must match the recorded digest);
* a grid's data in the checkout (``reference/quick/table1-v2``): the same, on the kept run records;
* a reference bundle (a folder with ``MANIFEST.json`` and ``runs.tar.xz``): verified against its manifest, its
  members rewritten in the same order, the manifest's file list and archive digest updated and the migration noted
  under ``migrated``. The new bundle is built beside the old one and swapped in only when complete.

A bundle's manifest also gets, for each override of the guidance fields of ``rl`` it was made under
(``rl.alpha_*``, ``rl.beta``, ``rl.guide_std``), the same override of ``oracle``: until the oracle had its own
section (``oracle``, :func:`omcrl.rl.train.oracle_config`) it trained under ``rl``'s, so the shipped quick bundle's
``rl.alpha_decay_steps=75000`` was its oracle's decay too, and without ``oracle.alpha_decay_steps=75000`` its oracle
(and the students found through the oracle's file) would be looked for under another key. Only the manifest changes.

A bundle's cached evaluations, until they became runs (:func:`omcrl.eval.stage.cached_episodes`), were a pair of files
``eval/<label>/seed<k>/<scene>-<key[:12]>.csv`` and ``.json`` (the full key, the rows, the CSV's digest); each is now a
run folder ``<scene>-<key>/`` holding ``episodes.csv`` (the same bytes) and a ``run.json`` that records, as a cache run
does, its identity (:func:`omcrl.eval.stage.evaluation_identity`), rows and digest. The identity is not in the old
record, only its hash: it is rebuilt from the bundle's own policy (found by this code's run registry in a scratch copy)
for the lanes the preset and a single lane give, and taken only when it hashes to the recorded key; a cache whose key
no candidate gives, or whose CSV does not match its digest, stops the script, naming it. A results folder's caches in
the old form are not migrated (nothing records their configuration): they are not read any more and are flown again
on first use.

What is already migrated is left alone, so running it twice changes nothing. A ``done.json`` whose key is not its
``run.json``'s, or an encoder that does not match its recorded digest, stops the script, naming the file, before it
writes anything for that folder. (The quick bundle's ``done.json`` files predate the one identity rule and name the
old rule's ``hash`` instead of a key; the code before this migration therefore did not take its encoders for
finished, and would have pretrained them again.)
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import shutil
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from omcrl.config import GUIDANCE_FIELDS, config_hash, load_config
from omcrl.eval.stage import EPISODES, PLANNER_NAMES, evaluation_identity
from omcrl.pipeline.reference import (
    ARCHIVE,
    MANIFEST,
    bundle_suite,
    manifest_overrides,
    registered_runs,
    verify_reference,
    write_archive,
)
from omcrl.pipeline.storage import sha256
from omcrl.runs import cache_run
from omcrl.utils.io import atomic_write_text, bytes_digest, file_digest

MIGRATION = "pretraining records: done.json merged into run.json (scripts/migrate_runs.py, issue 43)"
EVAL_MIGRATION = (
    "evaluation caches: <scene>-<key>.csv/.json became run folders <scene>-<key>/{run.json, episodes.csv} "
    "(scripts/migrate_runs.py, issue 43)"
)
# An evaluation cache before it was a run: eval/<label>/seed<k>/<scene>-<first 12 hex digits of its key>.json
OLD_CACHE = re.compile(r"eval/(?P<label>[^/]+)/seed(?P<seed>\d+)/(?P<stem>[^/]+)-(?P<key>[0-9a-f]{12})\.json")
ORACLE_MIGRATION = "overrides: rl's guidance overrides given to the oracle's own section too (scripts/migrate_runs.py)"


def merged(run: dict, done: dict, where: str) -> dict:
    """``run.json`` with the completion ``done.json`` recorded, in the fields :meth:`omcrl.runs.Run.finish` writes."""
    if run.get("stage") != "pretrain":
        raise SystemExit(f"{where}: done.json beside a run of stage {run.get('stage')!r}; only pretraining wrote one")
    # A bundle re-keyed by scripts/rekey_reference.py kept its done.json from before the one identity rule: it names
    # the old rule's "hash", not the key (which that script checked when it moved the run).
    if "key" in done and done["key"] != run.get("key"):
        raise SystemExit(f"{where}: done.json names key {done['key']!r}, run.json {run.get('key')!r}")
    if "key" not in done and "hash" not in done:
        raise SystemExit(f"{where}: done.json names no key")
    if not done.get("encoder_digest"):
        raise SystemExit(f"{where}: done.json records no encoder_digest")
    out = dict(run)
    out.update(
        iterations=done["iterations"],
        final_loss=done.get("final_loss"),
        dataset=done.get("dataset", ""),
        dataset_fingerprint=done.get("dataset_fingerprint", ""),
        artifact_digest=done["encoder_digest"],
    )
    return out


def migrate_folders(root: Path) -> int:
    """Merge every ``done.json`` under ``root`` into its ``run.json``; returns how many."""
    n = 0
    for done_path in sorted(root.rglob("done.json")):
        d = done_path.parent
        if not (d / "run.json").is_file():
            raise SystemExit(f"{done_path}: no run.json beside it")
        run = json.loads((d / "run.json").read_text(encoding="utf-8"))
        done = json.loads(done_path.read_text(encoding="utf-8"))
        rec = merged(run, done, str(done_path))
        enc = d / "encoder.pt"
        if enc.is_file() and file_digest(enc) != rec["artifact_digest"]:
            raise SystemExit(f"{enc}: does not match the digest its done.json recorded; not migrating {d}")
        atomic_write_text(d / "run.json", json.dumps(rec, indent=1))
        done_path.unlink()
        n += 1
    return n


def migrate_bundle(bundle: Path) -> int:
    """Rewrite a bundle's pretraining records (see the module's text); returns how many runs changed."""
    manifest, contents = verify_reference(bundle)
    dones = [rel for rel in contents if rel.endswith("/done.json")]
    if not dones:
        return 0
    new: dict[str, bytes] = {}
    for rel, data in contents.items():  # the archive's order (encoders before the runs trained on them) is kept
        if rel.endswith("/done.json"):
            continue
        done_rel = rel.removesuffix("run.json") + "done.json"
        if rel.endswith("/run.json") and done_rel in contents:
            rec = merged(json.loads(data), json.loads(contents[done_rel]), f"{bundle}: {rel}")
            enc = contents.get(rel.removesuffix("run.json") + "encoder.pt")
            if enc is not None and bytes_digest(enc) != rec["artifact_digest"]:
                raise SystemExit(f"{bundle}: {rel}'s encoder does not match its recorded digest; not migrating")
            data = json.dumps(rec, indent=1).encode()
        new[rel] = data
    _write_bundle(bundle, manifest, new, {"what": MIGRATION, "runs": len(dones)})
    return len(dones)


def _write_bundle(bundle: Path, manifest: dict, members: dict[str, bytes], migration: dict) -> None:
    """Replace ``bundle`` by one of ``members`` (in their order) and ``manifest`` with ``migration`` noted, built
    beside it and verified whole before the swap."""
    tmp = bundle.with_name(bundle.name + ".migrating")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    out = dict(manifest)
    out["files"] = write_archive(tmp / ARCHIVE, members.items())
    out["archive"] = {"name": ARCHIVE, "sha256": sha256(tmp / ARCHIVE), "bytes": (tmp / ARCHIVE).stat().st_size}
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    out["migrated"] = [*manifest.get("migrated", []), {**migration, "made": when}]
    atomic_write_text(tmp / MANIFEST, json.dumps(out, indent=1, sort_keys=True) + "\n")
    verify_reference(tmp)  # the new bundle reads back whole before it replaces the old one
    old = bundle.with_name(bundle.name + ".old")
    shutil.rmtree(old, ignore_errors=True)
    bundle.rename(old)
    tmp.rename(bundle)
    shutil.rmtree(old)


def cache_record(manifest: dict, contents: dict[str, bytes], where: str) -> dict[str, tuple[str, dict]]:
    """For each old-form evaluation cache of a bundle (its ``.json`` member), the new run folder's member prefix
    and ``run.json`` (see the module's text)."""
    old = {rel: m for rel in contents if (m := OLD_CACHE.fullmatch(rel))}
    if not old:
        return {}
    with tempfile.TemporaryDirectory(prefix="migrate-") as scratch:
        cfg = load_config(manifest["preset"], overrides=[f"results_dir={scratch}"])
        cfg = cfg.with_suite(bundle_suite(manifest)).with_overrides(manifest_overrides(manifest))
        for rel, data in contents.items():
            if rel.startswith("runs/"):
                (cfg.run_root / rel).parent.mkdir(parents=True, exist_ok=True)
                (cfg.run_root / rel).write_bytes(data)
        found, _ = registered_runs(cfg, manifest)
        policies = {k: file_digest(d / "final.pt") for k, d in found.items()}
    out = {}
    for rel, m in old.items():
        meta = json.loads(contents[rel])
        csv = contents.get(rel.removesuffix(".json") + ".csv")
        if csv is None or bytes_digest(csv) != meta.get("digest"):
            raise SystemExit(f"{where}: {rel}'s episodes are missing or do not match its digest; not migrating")
        planner = m["label"] in PLANNER_NAMES  # a planner is keyed by its name and flies one lane
        policy = m["label"] if planner else policies.get(f"{m['label']}/seed{m['seed']}")
        if policy is None:
            raise SystemExit(f"{where}: {rel} is an evaluation of no run the bundle holds; not migrating")
        env, rows, seed = replace(cfg.env, scene=m["stem"]), int(meta["rows"]), int(m["seed"])
        lanes = (1,) if planner else (cfg.eval.lanes, 1)
        idents = (evaluation_identity(cfg, policy, env, rows, planner=planner, lanes=n) for n in lanes)
        ident = next((i for i in idents if config_hash(i) == meta["key"]), None)
        if ident is None:
            raise SystemExit(f"{where}: {rel}'s key is not this code's for its policy and scene; not migrating")
        run = cache_run(rel.rsplit("/", 1)[0], m["stem"], seed, ident)
        rec = {"stage": run.stage, "method": run.method, "seed": seed, "key": run.key, "identity": run.identity}
        out[rel] = (run.dir.as_posix(), {**rec, "rows": rows, "artifact_digest": meta["digest"]})
    return out


def migrate_bundle_evaluations(bundle: Path) -> int:
    """Make a bundle's old-form evaluation caches run folders (see the module's text); returns how many."""
    manifest, contents = verify_reference(bundle)
    records = cache_record(manifest, contents, str(bundle))
    if not records:
        return 0
    new: dict[str, bytes] = {}
    for rel, data in contents.items():  # each cache's two members become its run's two, in the same place
        if rel in records:
            continue
        meta_rel = rel.removesuffix(".csv") + ".json"
        if rel.endswith(".csv") and meta_rel in records:
            folder, rec = records[meta_rel]
            new[f"{folder}/run.json"] = json.dumps(rec, indent=1).encode()
            new[f"{folder}/{EPISODES}"] = data
            continue
        new[rel] = data
    _write_bundle(bundle, manifest, new, {"what": EVAL_MIGRATION, "evaluations": len(records)})
    return len(records)


def oracle_overrides(overrides: list[str]) -> list[str]:
    """``overrides`` with an ``oracle.<field>=v`` added after each ``rl.<field>=v`` of a guidance field that has none,
    and ``rl.oracle_guide=v`` renamed ``oracle.guide=v``."""
    out: list[str] = []
    for o in overrides:
        key, _, value = o.partition("=")
        section, _, name = key.strip().partition(".")
        if section == "rl" and name == "oracle_guide":
            out.append(f"oracle.guide={value}")
            continue
        out.append(o)
        if section == "rl" and name in GUIDANCE_FIELDS and not any(x.startswith(f"oracle.{name}=") for x in overrides):
            out.append(f"oracle.{name}={value}")
    return out


def migrate_manifest_overrides(bundle: Path) -> int:
    """Give the oracle's section the guidance overrides a bundle was made under (see the module's text); returns how
    many overrides were added or renamed."""
    manifest, _ = verify_reference(bundle)
    before = list(manifest.get("overrides", []))
    after = oracle_overrides(before)
    if after == before:
        return 0
    out = dict(manifest, overrides=after)
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    changed = [o for o in after if o not in before]
    out["migrated"] = [*manifest.get("migrated", []), {"what": ORACLE_MIGRATION, "made": when, "added": changed}]
    atomic_write_text(bundle / MANIFEST, json.dumps(out, indent=1, sort_keys=True) + "\n")
    verify_reference(bundle)
    return len(changed)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+", type=Path, help="results folders, grid data folders or bundle folders")
    a = ap.parse_args(argv)
    for p in a.paths:
        if not p.is_dir():
            raise SystemExit(f"{p}: not a folder")
        if (p / MANIFEST).is_file():
            print(f"{p}: bundle, {migrate_bundle(p)} pretraining runs migrated")
            print(f"{p}: bundle, {migrate_manifest_overrides(p)} overrides given to the oracle's section")
            print(f"{p}: bundle, {migrate_bundle_evaluations(p)} evaluation caches made runs")
        else:
            print(f"{p}: {migrate_folders(p)} pretraining runs migrated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
