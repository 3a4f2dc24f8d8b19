#!/usr/bin/env bash
# Reproduce OMC-RL (Oracle-Guided Masked Contrastive RL) with the omcrl kit.
#
#   ./reproduce.sh --test    run the test suite (pytest on every core; slow tests excluded, notebook smoke runs included)
#   ./reproduce.sh --smoke   run the notebook chain with the tiny CI preset (minutes)
#   ./reproduce.sh --quick   run the notebook chain with the laptop preset (hours on 2 CPU cores; see the README)
#   ./reproduce.sh --paper   run the notebook chain at the paper's scale (needs a GPU; hours to days)
#   ./reproduce.sh --lab     install JupyterLab (the 'lab' extra) and open the notebooks in it
#
# A chain mode names its preset; --preset among its extra arguments is refused (use --quick, not
# --smoke --preset quick). Each chain ends by printing results/<preset>/summary.md.
# Each mode first creates .venv (Python 3.11) and installs the kit when .venv is missing, when
# pyproject.toml changed since the last install, or when `import omcrl, torch, pybullet` fails.
# Extra arguments go to pytest (--test) or to `python -m omcrl notebooks` (other modes), e.g.
#   ./reproduce.sh --test -k config         ./reproduce.sh --quick --set rl.total_steps=50000
#   ./reproduce.sh --quick --skip 06        the chain without the ablation sweeps (notebook 06: hours more)
#   ./reproduce.sh --quick --only 05,07     only these notebooks (their inputs must exist)
#   ./reproduce.sh --quick --from-reference [PATH]
#                                           start from the trained reference runs (reference/quick/bundle, or PATH),
#                                           verified, instead of training: then notebooks 07-09 (minutes)
# Environment: PYTHON=/path/to/python3.11 to choose the interpreter for a new .venv;
# TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu for the CPU-only torch build (see the README).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$ROOT/.venv"
STAMP="$VENV/.omcrl-install-stamp"

say() { printf '[reproduce] %s\n' "$*"; }
die() { printf '[reproduce] error: %s\n' "$1" >&2; exit "${2:-1}"; }

usage() {
  awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "${BASH_SOURCE[0]}"
}

mode="${1:-}"
case "$mode" in
  --test | --smoke | --quick | --paper | --lab) shift ;;
  -h | --help) usage; exit 0 ;;
  "") usage >&2; exit 2 ;;
  *) printf '[reproduce] error: unknown mode %s\n\n' "$mode" >&2; usage >&2; exit 2 ;;
esac

cd "$ROOT"

pick_python() {
  if [[ -n "${PYTHON:-}" ]]; then
    echo "$PYTHON"
  elif command -v python3.11 >/dev/null 2>&1; then
    echo python3.11
  elif command -v python3 >/dev/null 2>&1 &&
       python3 -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
    echo python3
  else
    die "Python 3.11 not found (install it, or set PYTHON=/path/to/python3.11)"
  fi
}

file_hash() {
  if command -v sha256sum >/dev/null 2>&1; then
    sha256sum "$1" | cut -d' ' -f1
  else
    shasum -a 256 "$1" | cut -d' ' -f1
  fi
}

# Run from / so that the repository folder on sys.path cannot hide a missing install of omcrl.
import_check() { (cd / && "$VENV/bin/python" -c 'import omcrl, torch, pybullet') >/dev/null 2>&1; }

ensure_venv() {
  local py want reason=""
  if [[ ! -x "$VENV/bin/python" ]]; then
    py="$(pick_python)"
    say "creating .venv with $py ($("$py" --version 2>&1))"
    "$py" -m venv "$VENV"
    reason="new .venv"
  fi
  want="$(file_hash "$ROOT/pyproject.toml")"
  if [[ -z "$reason" ]]; then
    if [[ ! -f "$STAMP" ]]; then
      reason="no record of an install by this script"
    elif [[ "$(cat "$STAMP")" != "$want" ]]; then
      reason="pyproject.toml changed since the last install"
    elif ! import_check; then
      reason="import check failed"
    fi
  fi
  if [[ -z "$reason" ]]; then
    say ".venv is up to date"
    return
  fi
  say "installing the kit into .venv ($reason)"
  rm -f "$STAMP"
  # torch first, pinned, so that nothing later pulls a CUDA build of several GB.
  # TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu picks the CPU build on a machine where PyPI's default
  # is the CUDA one (standard Linux x86-64: several GB of nvidia-* wheels).
  if [[ -n "${TORCH_INDEX_URL:-}" ]]; then
    say "pip install torch==2.13.0 --index-url $TORCH_INDEX_URL"
    "$VENV/bin/python" -m pip install --quiet torch==2.13.0 --index-url "$TORCH_INDEX_URL"
  else
    say "pip install torch==2.13.0"
    "$VENV/bin/python" -m pip install --quiet torch==2.13.0
  fi
  say "pip install -e '.[dev]'"
  "$VENV/bin/python" -m pip install --quiet -e "$ROOT[dev]"
  import_check || die "the install finished but 'import omcrl, torch, pybullet' fails in .venv"
  echo "$want" >"$STAMP"
  say "install done"
}

# --from-reference [PATH]: taken out of the arguments here (the notebooks command does not know it).
from_ref=""
ref_path=""
rest=()
while [[ $# -gt 0 ]]; do
  if [[ "$1" == --from-reference ]]; then
    [[ "$mode" == --test || "$mode" == --lab ]] && die "--from-reference goes with a chain mode (--smoke, --quick, --paper)" 2
    from_ref=1
    if [[ $# -gt 1 && "$2" != -* ]]; then ref_path="$2"; shift; fi
  else
    rest+=("$1")
  fi
  shift
done
set -- ${rest[@]+"${rest[@]}"}

for arg in "$@"; do
  if [[ "$mode" != --test && ( "$arg" == --preset || "$arg" == --preset=* ) ]]; then
    die "$mode already chooses the preset; drop '$arg' (e.g. ./reproduce.sh --quick, not --smoke --preset quick)" 2
  fi
done

ensure_venv

# Two intra-op threads for the chain on this 2-core target; one for the tests, which already run a worker per core
# (tests/conftest.py keeps a value given here): two threads each oversubscribe the cores, and OpenMP's spin-waits
# (t-SNE, torch) then burn them. Measured idle, 2026-12-05: the full suite took 683 s and 18 min CPU with 2, and 539 s
# and 14 min 21 s CPU with 1. A value set by the caller is kept either way.
if [[ "$mode" == --test ]]; then
  export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
else
  export OMP_NUM_THREADS="${OMP_NUM_THREADS:-2}"
fi
export MPLBACKEND=Agg
export PATH="$VENV/bin:$PATH"
PY="$VENV/bin/python"

case "$mode" in
  --test)
    # Every core (pytest-xdist; each test is single-threaded, tests/conftest.py), a test module per unit of the
    # schedule (its fixtures built once), handed out in collection order (xdist would sort modules by their number of
    # tests; tests/conftest.py puts the longest first); -n N, -n 0 or -p no:xdist among the arguments chooses otherwise.
    par=(-n auto --dist loadfile --no-loadscope-reorder)
    for arg in "$@"; do
      case "$arg" in -n | -n* | --numprocesses* | no:xdist) par=() ;; esac
    done
    say "running tests: python -m pytest ${par[*]+"${par[*]} "}$*"
    set +e
    "$PY" -m pytest ${par[@]+"${par[@]}"} "$@"
    rc=$?
    set -e
    say "pytest exit code $rc"
    exit "$rc"
    ;;
  --lab)
    if ! "$PY" -c 'import jupyterlab' 2>/dev/null; then
      say "pip install -e '.[dev,lab]' (JupyterLab)"
      "$PY" -m pip install --quiet -e "$ROOT[dev,lab]"
    fi
    say "opening JupyterLab in notebooks/ (results and data resolve from $ROOT whatever the working directory)"
    extra=()
    if [[ "$(id -u)" == 0 ]]; then
      # Jupyter refuses to run as root unless told to; containers usually run as root.
      say "running as root (a container?): passing --allow-root to JupyterLab"
      extra+=(--allow-root)
    fi
    exec "$VENV/bin/jupyter" lab --notebook-dir="$ROOT/notebooks" "${extra[@]}" "$@"
    ;;
  --smoke | --quick | --paper)
    preset="${mode#--}"
    if [[ "$preset" == paper ]] && ! "$PY" -c 'import sys, torch; sys.exit(not torch.cuda.is_available())' 2>/dev/null; then
      say "warning: no CUDA device visible to torch; the paper preset on a CPU takes days"
    fi
    # A notebook that --only or --skip does not name is refused now, not after the unpack and the set-up.
    "$PY" -c 'import sys; from omcrl.pipeline.notebooks import check_choice; sys.exit(check_choice(sys.argv[1:]))' "$@" ||
      exit 2
    if [[ -n "$from_ref" ]]; then
      say "unpacking the reference runs of preset $preset (verified against their manifest)"
      "$PY" -m omcrl reference --preset "$preset" ${ref_path:+--from "$ref_path"}
      # The bundle's runs belong to one scene suite (v1 for bundles made before v2): the notebooks use its scenes.
      while IFS= read -r line; do
        [[ -n "$line" ]] && set -- "$@" --set "$line"
      done < <("$PY" -c 'import sys; from omcrl.pipeline.reference import bundle_overrides as b
print("\n".join(b(sys.argv[1], sys.argv[2] or None)))' "$preset" "$ref_path")
      chosen=""
      for arg in "$@"; do [[ "$arg" == --only* || "$arg" == --skip* ]] && chosen=1; done
      # The trained runs are there: the tables, interpretability and deployment need no training.
      [[ -z "$chosen" ]] && set -- "$@" --only 07,08,09
    fi
    say "running the notebook chain with preset $preset (executed copies in results/$preset/executed/)"
    "$PY" -m omcrl notebooks --preset "$preset" "$@"
    say "done: results in results/$preset/"
    ;;
esac
