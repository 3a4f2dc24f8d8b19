"""Re-key a reference bundle once, from the identity rules before issue 43 to the one rule after it.

    python scripts/rekey_reference.py [--preset quick] [--bundle reference/quick/bundle]

The runs' files do not change (weights, metrics, configs, per-episode rows); only their folder keys and the
identities in ``run.json`` do, and the learned methods' cached evaluations get their new cache keys. What it does:

1. verifies the bundle against its manifest and reads it into a scratch results folder;
2. checks that every run's ``config.yaml`` is the configuration the bundle is found under (its suite's overrides
   on the preset), section by section under the new rule, so the runs it re-keys are the runs the registry asks
   for, and that every ``run.json`` still hashes to its old key;
3. moves each run to the folder the registry of this code names (encoders, then the oracle, then the policies:
   a policy's identity takes its upstream files' digests, which do not change), recording the old key
   (``rekeyed_from``);
4. re-keys each learned method's cached evaluation after checking that the old rule (written out below, the only
   place it survives) gives its recorded key. The planners' cached evaluations are left out: their old keys
   hashed the planner modules as they were then, so nothing proves they are today's planners' episodes; they are
   flown again on first use (minutes);
5. packs the re-keyed runs with :func:`omcrl.pipeline.reference.pack_reference` (no second rounding: the weights
   are the bundle's float16-rounded ones) and keeps the old manifest's provenance (commit, date, rounding).

Running it on a bundle already re-keyed is refused (its manifest says ``rekeyed``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
from pathlib import Path

from omcrl.config import config_hash, load_config, section_identity
from omcrl.eval.stage import evaluation_identity
from omcrl.pipeline.reference import MANIFEST, bundle_overrides, pack_reference, registered_runs, verify_reference
from omcrl.pretrain.train import pretrain_run
from omcrl.rl.methods import METHODS, encoder_config
from omcrl.rl.train import oracle_run
from omcrl.runs import RUN_FILE, read_identity, run_key
from omcrl.utils.io import atomic_write_text, file_digest


def old_eval_key(cfg, policy_digest: str, scene: str, episodes: int, lanes: int) -> str:
    """The cache key of a learned policy's evaluation before issue 43 (omcrl.eval.stage at b2d3314)."""
    env = dataclasses.asdict(cfg.env)
    env.pop("scene")
    if env.pop("renderer") not in ("auto", "tiny"):
        raise SystemExit("the old rule left the renderer out only for TinyRenderer; this bundle was not made so")
    family, version = scene.rsplit("-v", 1)
    ident = {"policy": policy_digest, "env": env, "scene": family if version == "0" else scene, "episodes": episodes}
    if lanes != 1:
        ident["lanes"] = lanes
    return config_hash({**ident, "seed_offset": cfg.eval.seed_offset})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="quick")
    ap.add_argument("--bundle", default=None)
    a = ap.parse_args(argv)
    bundle = Path(a.bundle or f"reference/{a.preset}/bundle")
    manifest, contents = verify_reference(bundle, a.preset)
    if manifest.get("rekeyed"):
        raise SystemExit(f"{bundle}: already re-keyed ({manifest['rekeyed']})")
    scratch = Path(tempfile.mkdtemp(prefix="rekey-"))
    try:
        overrides = bundle_overrides(a.preset, bundle)
        cfg = load_config(a.preset, overrides=[f"results_dir={scratch / 'results'}", *overrides])
        root = cfg.run_root
        for rel, data in contents.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(data)
        runs = {}
        for rec_path in sorted((root / "runs").glob("*/*/seed*/" + RUN_FILE)):
            rec = read_identity(rec_path.parent)
            if run_key(rec["identity"]) != rec["key"]:
                raise SystemExit(f"{rec_path}: its identity does not hash to its key {rec['key']}")
            runs[rec_path.parent] = rec
        # The bundle's runs were trained under the configuration it is found under: check it field by field.
        for d in runs:
            run_cfg = load_config(a.preset, path=d / "config.yaml", overrides=[f"results_dir={scratch / 'results'}"])
            want = cfg if d.parts[-3] == "rl" else encoder_config(cfg, METHODS[_student_of(runs, d)])
            for sec in ("env", "data", "pretrain", "rl"):
                got, exp = section_identity(getattr(run_cfg, sec)), section_identity(getattr(want, sec))
                if got != exp:
                    raise SystemExit(f"{d / 'config.yaml'}: section {sec} is {got}, the bundle's config {exp}")
        moved: dict[str, str] = {}

        def move(old, new) -> None:
            rec = runs.pop(old)
            new.dir.parent.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(str(old.parent), str(new.dir.parent))
            rec.update(key=new.key, identity=new.identity, rekeyed_from=rec["key"])
            atomic_write_text(new.dir / RUN_FILE, json.dumps(rec, indent=1))
            moved[f"{rec['stage']}/{rec['method']}-{rec['rekeyed_from']}"] = new.dir.parent.name

        def only(stage: str, method: str):
            found = [d for d, r in runs.items() if r["stage"] == stage and r["method"] == method]
            if len(found) != 1:
                raise SystemExit(f"the bundle holds {len(found)} {stage} runs of {method}, expected one")
            return found[0]

        methods = [m for m in manifest["methods"] if METHODS[m].learned]
        for m in methods:
            spec = METHODS[m]
            if spec.features == "frozen":
                enc = pretrain_run(encoder_config(cfg, spec))
                if not enc.dir.exists():
                    move(only("pretrain", enc.method), enc)
        move(only("rl", "oracle"), oracle_run(cfg))
        for m in methods:
            if m != "oracle":
                spec = METHODS[m]
                new = spec.recipe.run(cfg, spec)
                if new is None:
                    raise SystemExit(f"{m}: an upstream run is missing after re-keying")
                move(only("rl", m), new)
        if runs:
            raise SystemExit(f"runs left over, not asked for by any method: {sorted(str(d) for d in runs)}")
        found, missing = registered_runs(cfg, {"methods": methods, "seeds": manifest["seeds"], "files": _files(root)})
        if missing:
            raise SystemExit(f"the registry does not find {missing} after re-keying")
        # Evaluation caches: learned methods re-keyed (old key checked), planners dropped.
        evals = 0
        for meta_path in sorted((root / "eval").glob("*/seed*/*.json")):
            label, seed = meta_path.parts[-3], int(meta_path.parts[-2].removeprefix("seed"))
            csv_path = meta_path.with_suffix(".csv")
            if label not in methods:
                meta_path.unlink(), csv_path.unlink()
                continue
            meta = json.loads(meta_path.read_text())
            scene = meta_path.stem.rsplit("-", 1)[0]
            policy = found[f"{label}/seed{seed}"] / "final.pt"
            digest, rows = file_digest(policy), int(meta["rows"])
            lanes = next(
                (n for n in (cfg.eval.lanes, 1) if old_eval_key(cfg, digest, scene, rows, n) == meta["key"]), 0
            )
            if not lanes:
                raise SystemExit(f"{meta_path}: its key is not the old rule's for {policy}; not re-keying it")
            env = dataclasses.replace(cfg.env, scene=scene)
            key = config_hash(evaluation_identity(cfg, digest, env, rows, planner=False, lanes=lanes))
            meta["key"] = key
            new_csv = csv_path.with_name(f"{scene}-{key[:12]}.csv")
            csv_path.rename(new_csv)
            meta_path.unlink()
            atomic_write_text(new_csv.with_suffix(".json"), json.dumps(meta))
            evals += 1
        out = scratch / "bundle"
        res = pack_reference(cfg, seeds=manifest["seeds"], methods=methods, out=out, rounded=False, progress=False)
        new_manifest = dict(res.manifest)
        made = new_manifest["made"]
        for k in ("commit", "made", "rounded", "rounding"):
            new_manifest[k] = manifest[k]
        new_manifest["rekeyed"] = {
            "by": "scripts/rekey_reference.py (issue 43: one identity rule)",
            "made": made,
            "runs": moved,
            "evaluations": evals,
            "planner_evaluations_dropped": True,
        }
        atomic_write_text(out / MANIFEST, json.dumps(new_manifest, indent=1, sort_keys=True) + "\n")
        shutil.rmtree(bundle)
        shutil.move(str(out), str(bundle))
        print(f"re-keyed {len(moved)} runs and {evals} evaluations; {bundle} rewritten")
        for old, new in moved.items():
            print(f"  {old} -> {new}")
        return 0
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _student_of(runs: dict, d: Path) -> str:
    """A learned method whose encoder the pretraining run ``d`` is (by the encoder's digest in a policy's identity)."""
    digest = json.loads((d / "done.json").read_text())["encoder_digest"]
    for r in runs.values():
        if r["identity"].get("encoder_digest") == digest:
            return r["method"]
    raise SystemExit(f"{d}: no policy in the bundle was trained on this encoder")


def _files(root: Path) -> dict[str, dict]:
    return {p.relative_to(root).as_posix(): {} for p in root.rglob("*") if p.is_file()}


if __name__ == "__main__":
    sys.exit(main())
