#!/usr/bin/env bash
# Run what is left of a grid over seeds, one variant at a time, and commit each finished variant's grid data.
#
#   scripts/grid_session.sh [--grid table1] [--seeds 0,1,2,3,4] [--variants oracle,ours,...] [--dir ../omcrl-grid]
#                           [--backend local|ray] [--bundle-seed 2|none] [--parts bundle-parts] [--by seed|variant]
#                           [--also GRID] [--set FIELD=VALUE ...] [--ship-only]
#
# A session is shorter than the grid (about 6 machine-hours a seed at the quick preset), so this is what a session
# starts first, in the background, with its log on disk:
#
#   nohup scripts/grid_session.sh --seeds 1 > ../grid.log 2>&1 &
#
# It trains from a detached worktree of HEAD (--dir), so code edits in this checkout cannot touch a running job.
# After each variant of each seed, the worktree's reference/<preset>/<grid>-<suite>/ is copied into this checkout
# and committed alone (`git commit -- <that folder>`: nothing else staged here is committed with it). A variant whose
# episodes are already recorded there is not trained again, so a session that ends midway loses only the variant in
# flight. The README's and docs/results.md's blocks (rendered by this checkout's code: Table I, its confirmation, the
# budget ladder) are rebuilt and committed after each ship (`summary --readme`), unless they hold uncommitted edits.
#
# A teacher's weights (the oracle's final.pt, ~15 MB a seed) are committed with its records; once every evaluation
# that needs them is recorded, they are released (`sweep --release-teachers`: a pointer to their git blob replaces
# them, so reference/ stays under its 60 MB) and that is committed too.
#
# The reference bundle (reference/<preset>/bundle: every learned method's weights at one seed) needs that seed's runs
# together, but a session may start on a fresh machine with only what was committed. So each learned variant of the
# bundle seed (--bundle-seed, default 2 for table1; none: off) is packed on its own as soon as its run finishes
# (`reference --pack --methods V`: rounded, re-keyed, flown again), into reference/<preset>/bundle-parts/<V>/,
# committed, and retired to git history (a pointer stays) in the next commit. Once every part is in:
#
#   python -m omcrl reference --preset quick --merge reference/quick/bundle-parts --from reference/quick/bundle
#
# --parts NAME: the folder under reference/<preset>/ the parts go to (default bundle-parts, the published bundle's).
# Another seed's weights kept the same way (e.g. the look attribution's retrained seeds, issue 75) get a folder of
# their own: --bundle-seed 3 --parts bundle-parts-seed3. The retrain grid's policies (table1-retrain: a seed whose
# Table I run cannot be retrained as it was, trained again and flown in all three settings) are not Table I's, so
# their parts go to a folder that says so: --grid table1-retrain --bundle-seed 0 --parts bundle-parts-retrain-seed0.
#
# --also GRID: after each variant of each seed is shipped, GRID's same variant and seed run and are shipped too. It is
# for a grid that re-flies this grid's runs in other layouts (table1-confirm): a policy's weights live only on the
# machine that trained it (only the records are committed), so the other grid flies it before a session ends.
#
# --ship-only: run nothing; commit what the worktree (--dir) recorded since the last ship, as a finished variant's
# ship does (records, a teacher's weights, the pages). A variant is shipped when it ends, and one longer than a session
# (the RL ladder's: its oracle x3, then its student) would otherwise lose its finished teacher with the machine. At
# the end of a session: stop the stream (kill -INT the sweep; a training keeps its last checkpoint), then
#
#   scripts/grid_session.sh --grid ladder-rl --dir ../omcrl-grid-rl --ship-only
#
# The next session, on any machine, finds the teacher recorded and trains only its student. Refused while a sweep
# runs in that worktree (a record half written would be committed).
#
# --variants: labels of the grid's variants, in the order to run them (default: Table I's teacher-first order for
# table1 and table1-confirm, every variant of any other grid in its order, e.g. --grid decay runs linear, exp, fixed).
#
# --by sets the loop's order: seed (default: every variant of seed 0, then of seed 1, ...; whole rows of Table I
# first) or variant (every seed of the first variant, then of the next; a budget ladder's point gets its intervals
# before a costlier point starts, e.g. --grid ladder-pretrain --by variant --seeds 0,1,2).
set -euo pipefail
# The whole script is one compound command, read before any of it runs: a checkout that edits this file (a pull,
# an edit in place) while a grid runs for hours cannot change what the running loop reads next.
{

grid=table1
seeds=0,1,2,3,4
# Teacher first (its students need it), then the frozen-encoder students (about 31 min each), then the pixel
# runs (about 70 min each), so that what a session finishes is as many whole rows as it can be.
table1_variants=oracle,ours,ours-noOT,ours-lapf,ours-random,ours-blind,curl,curl-phi,npe,npe-ot,ppo
variants=""  # default: Table I's order above for table1 (less the controls for table1-confirm, table1-boxlook), every
#             variant of any other grid
preset=quick
backend=local
bundle_seed=default
parts=bundle-parts
by=seed
also=""
ship_only=""
sets=()
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dir="$(dirname "$root")/omcrl-grid"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --grid) grid="$2"; shift 2 ;;
    --seeds) seeds="$2"; shift 2 ;;
    --variants) variants="$2"; shift 2 ;;
    --preset) preset="$2"; shift 2 ;;
    --dir) dir="$2"; shift 2 ;;
    --backend) backend="$2"; shift 2 ;;
    --bundle-seed) bundle_seed="$2"; shift 2 ;;
    --parts) parts="$2"; shift 2 ;;
    --by) by="$2"; shift 2 ;;
    --also) also="$2"; shift 2 ;;
    --ship-only) ship_only=1; shift ;;
    --set) sets+=(--set "$2"); shift 2 ;;  # e.g. --set sweep.storage=/shared/omcrl (an embedded Ray resumes from it)
    *) echo "grid_session: unknown argument $1" >&2; exit 2 ;;
  esac
done
[[ "$by" == seed || "$by" == variant ]] || { echo "grid_session: --by must be seed or variant, got $by" >&2; exit 2; }
if [[ "$bundle_seed" == default ]]; then
  # Seeds 0 and 1 of the v2 grid were trained on machines since lost, with only their records kept.
  [[ "$grid" == table1 ]] && bundle_seed=2 || bundle_seed=none
fi
py="$root/.venv/bin/python"

# git add / commit in this checkout, waiting out another writer's index lock (a second grid session, or a person
# committing by hand, holds .git/index.lock for a moment): a lock that outlasts 60 s, or any other failure, fails.
git_write() {
  local i
  for i in $(seq 30); do
    git -C "$root" "$@" && return 0
    [[ -e "$(git -C "$root" rev-parse --git-dir)/index.lock" ]] || return 1
    echo "grid_session: git $1 waits for another writer's index lock ($i)" >&2
    sleep 2
  done
  return 1
}
[[ -x "$py" ]] || { echo "grid_session: $py not found; run ./reproduce.sh --test once to make .venv" >&2; exit 2; }
if [[ -z "$variants" ]]; then
  if [[ "$grid" == table1 ]]; then
    variants="$table1_variants"
  elif [[ "$grid" == table1-confirm || "$grid" == table1-boxlook ]]; then
    # Table I's order without the controls, which these grids do not fly (omcrl.pipeline.grids.CONTROL_METHODS).
    variants="${table1_variants/,ours-random,ours-blind/}"
  else  # the grid's labels, in its order (an unknown grid fails here, naming the known ones)
    variants="$("$py" -c 'import sys; from omcrl.pipeline.grids import grid_variants
print(",".join(v.label for v in grid_variants(sys.argv[1])))' "$grid")" || exit 2
  fi
fi

if [[ -n "$ship_only" ]]; then
  [[ -d "$dir" ]] || { echo "grid_session: --ship-only: no worktree $dir (nothing recorded to ship)" >&2; exit 2; }
  for proc in /proc/[0-9]*; do
    [[ "$(readlink "$proc/cwd" 2>/dev/null)" == "$(cd "$dir" && pwd -P)" ]] || continue
    if tr '\0' ' ' <"$proc/cmdline" 2>/dev/null | grep -q -- "-m omcrl sweep"; then
      echo "grid_session: --ship-only: a sweep runs in $dir (pid ${proc#/proc/}); stop it first (kill -INT ${proc#/proc/})" >&2
      exit 2
    fi
  done
fi
if [[ -n "$ship_only" ]]; then
  :  # the worktree stays at the commit its sweep ran (checking it out again would not touch results/ or reference/)
elif [[ ! -d "$dir" ]]; then
  git -C "$root" worktree add --detach "$dir" HEAD >/dev/null
else
  # A worktree left by an earlier session: bring it to this checkout's HEAD (what it recorded was committed here by
  # ship; its results/ folder, ignored by git, keeps finished runs and checkpoints to resume).
  git -C "$dir" checkout -q -f --detach "$(git -C "$root" rev-parse HEAD)"
fi
echo "grid_session: worktree $dir at $(git -C "$dir" rev-parse --short HEAD), grid $grid, seeds $seeds"

ship() {  # $1: what finished, $2: the grid whose record it is (default: --grid)
  local src sub g="${2:-$grid}"
  # <grid>-<suite> (suites are v0, v1, v2...): table1-* would also take table1-confirm-v2, another grid's folder.
  for src in "$dir"/reference/"$preset"/"$g"-v[0-9]*/; do
    [[ -d "$src" ]] || continue  # the pattern itself: the grid recorded nothing yet (its sweep failed early)
    sub="${src#"$dir"/}"
    mkdir -p "$root/$sub"
    cp -a "$src". "$root/$sub"
    git_write add -- "$sub"
    drop_stale_copies "$sub"
    if ! git -C "$root" diff --cached --quiet -- "$sub"; then
      # Name what the commit holds (<variant>/seed<k>), not only what just ran: a variant interrupted by the end of
      # an earlier session may have recorded its pretraining there, and it is shipped with whatever runs next.
      local held
      held="$(git -C "$root" diff --cached --name-only -- "$sub" | awk -F/ 'NF > 5 {print $4 "/" $5}' | sort -u |
        paste -sd, -)"
      git_write commit -q -m "$g grid: $1 recorded ($sub${held:+: $held})" -- "$sub"
      echo "grid_session: committed $1 ($sub${held:+: $held})"
    fi
  done
  release "$1" "$g"
  summary "$1"
}

drop_stale_copies() {  # $1: a folder staged here; unstages the files that come back as they were when removed
  # A record taken out of this checkout on purpose (a run found wrong) may still lie untracked in the worktree, which
  # would ship it back byte for byte. A file staged as new whose content is the blob its deletion removed is such a
  # copy: it is unstaged and deleted in both places, with a line. A record trained again differs and is kept.
  local f gone
  while IFS= read -r f; do
    gone="$(git -C "$root" rev-list -n 1 HEAD -- "$f")"
    [[ -n "$gone" ]] || continue
    if [[ "$(git -C "$root" rev-parse -q --verify "$gone^:$f" 2>/dev/null || true)" == "$(git -C "$root" rev-parse ":$f")" ]]; then
      echo "grid_session: $f is the copy of what ${gone:0:7} removed: not shipped, and removed from the worktree"
      git -C "$root" rm -q --cached -- "$f"
      rm -f -- "${root:?}/$f" "${dir:?}/$f"
    fi
  done < <(git -C "$root" diff --cached --name-only --diff-filter=A -- "$1")
}

summary() {  # $1: after what; rebuilds and commits the generated blocks and figures
  # A commit of grid data with the README's block left as it was fails test_summary (the block must match the data),
  # so the blocks follow each ship of any grid the pages render (Table I, its confirmation, the ladder; a grid they
  # do not render leaves them as they are). Skipped, with a line, while those files hold edits of someone else's.
  local docs=(README.md docs/results.md docs/generalization.md docs/glossary.md "docs/figures/$preset")
  if ! git -C "$root" diff --quiet HEAD -- "${docs[@]}"; then
    echo "grid_session: the generated pages have uncommitted edits: blocks not rebuilt (run: python -m omcrl summary --preset $preset --readme)"
    return 0
  fi
  # The pages are written by this checkout's code: with uncommitted edits in the library or its templates they would
  # be committed as that code renders them, ahead of the code itself (it happened once, 2cdc2b0).
  if ! git -C "$root" diff --quiet HEAD -- omcrl; then
    echo "grid_session: the library has uncommitted edits: blocks not rebuilt (commit them, then run: python -m omcrl summary --preset $preset --readme)"
    return 0
  fi
  (cd "$root" && "$py" -m omcrl summary --preset "$preset" --readme) ||
    { echo "grid_session: summary --readme failed (the blocks stay as they were)"; return 0; }
  git_write add -- "${docs[@]}"
  if ! git -C "$root" diff --cached --quiet -- "${docs[@]}"; then
    git_write commit -q -m "README and docs/results.md blocks and figures rebuilt after $1 (summary --readme)" -- "${docs[@]}"
    echo "grid_session: committed the rebuilt README and docs/results.md blocks"
  fi
}

release() {  # $1: after what, $2: which grid; commits the teacher weights that nothing left to train needs any more
  local sub="reference/$preset/$2-v[0-9]*"  # a git pathspec: the grid's folders of every scene suite
  (cd "$root" && "$py" -m omcrl sweep "$2" --preset "$preset" --release-teachers) ||
    { echo "grid_session: release of teacher weights failed (they stay; the grid goes on)"; return 0; }
  # A grid's first session has no folder yet, and git add fails on a pathspec that matches nothing.
  compgen -G "$root/$sub" >/dev/null || return 0
  git_write add -- "$sub"
  if ! git -C "$root" diff --cached --quiet -- "$sub"; then
    git_write commit -q -m "$2 grid: teacher weights released after $1 (read from git history)" -- "$sub"
    echo "grid_session: committed the release of teacher weights"
  fi
}

bundle_part() {  # $1: seed, $2: variant that just finished; packs, commits and retires its bundle part
  [[ "$1" == "$bundle_seed" ]] || return 0
  # A part holds a method's weights: a variant that re-flies a method's run in other settings (table1-retrain's
  # "<method> box-look") has none of its own.
  "$py" -c 'import sys; from omcrl.rl.methods import METHODS; sys.exit(sys.argv[1] not in METHODS)' "$2" || return 0
  local sub="reference/$preset/$parts/$2"
  [[ -f "$root/$sub/MANIFEST.json" ]] && return 0
  echo "grid_session: packing $2 seed $1 as a part of the reference bundle ($sub)"
  # Packed in the worktree (its staging folder is large), then copied here whole.
  rm -rf "${dir:?}/$sub"
  (cd "$dir" && "$py" -m omcrl reference --preset "$preset" --set "seeds=[$1]" "${sets[@]}" --pack --methods "$2" \
    --from "$dir/$sub") || { echo "grid_session: packing $2 failed (no part; pack it by hand from $dir)"; return 0; }
  mkdir -p "$root/$sub"
  cp -a "$dir/$sub/." "$root/$sub"
  rm -rf "${dir:?}/$sub"
  git_write add -- "$sub"
  git_write commit -q -m "reference bundle: part $2 (seed $1) packed" -- "$sub"
  (cd "$root" && "$py" -m omcrl reference --preset "$preset" --retire --from "$sub") ||
    { echo "grid_session: retiring $sub failed (it stays in the checkout)"; return 0; }
  git_write add -A -- "$sub"
  git_write commit -q -m "reference bundle: part $2 (seed $1) retired to git history (a pointer stays)" -- "$sub"
  echo "grid_session: committed and retired the bundle part $2"
}

if [[ -n "$ship_only" ]]; then
  ship "what the stream finished before it was stopped"
  [[ -n "$also" ]] && ship "what the stream finished before it was stopped" "$also"
  exit 0
fi
release "an earlier session" "$grid"
IFS=, read -r -a seed_list <<<"$seeds"
IFS=, read -r -a variant_list <<<"$variants"
jobs=()  # "seed<TAB>variant", in the order --by asks (a variant's label may hold spaces, not tabs)
if [[ "$by" == seed ]]; then
  for seed in "${seed_list[@]}"; do for v in "${variant_list[@]}"; do jobs+=("$seed"$'\t'"$v"); done; done
else
  for v in "${variant_list[@]}"; do for seed in "${seed_list[@]}"; do jobs+=("$seed"$'\t'"$v"); done; done
fi
for job in "${jobs[@]}"; do
  seed="${job%%$'\t'*}" v="${job#*$'\t'}"
  echo "grid_session: seed $seed $v start $(date -u +%FT%TZ)"
  # A failed variant is run once more: a training run resumes from its last checkpoint (seed 2's oracle died once
  # on a NaN action near 300 k steps and finished from its checkpoint); a second failure is left for a person.
  for attempt in 1 2; do
    rc=0
    (cd "$dir" && "$py" -m omcrl sweep "$grid" --preset "$preset" --seeds "$seed" --backend "$backend" \
      --to-reference --variants "$v" "${sets[@]}") || rc=$?
    echo "grid_session: seed $seed $v exit $rc $(date -u +%FT%TZ) (attempt $attempt)"
    if [[ "$rc" == 0 ]]; then break; fi
  done
  ship "seed $seed, $v"
  if [[ "$rc" == 0 ]]; then bundle_part "$seed" "$v"; fi
  if [[ -n "$also" && "$rc" == 0 ]]; then
    rc_also=0
    (cd "$dir" && "$py" -m omcrl sweep "$also" --preset "$preset" --seeds "$seed" --backend "$backend" \
      --to-reference --variants "$v" "${sets[@]}") || rc_also=$?
    echo "grid_session: $also seed $seed $v exit $rc_also $(date -u +%FT%TZ)"
    ship "seed $seed, $v" "$also"
  fi
done
exit
}
