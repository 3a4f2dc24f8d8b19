#!/usr/bin/env bash
# The checks that need a GPU machine, as one short script: the EGL renderer (parity with TinyRenderer and its
# throughput), the training paths on CUDA, bf16 against fp32 on CUDA, and the paper preset's trainer rates.
#
#   scripts/device_check.sh [SECONDS]     # a deadline for the whole script (default 540); results go to $OUT
#
# It is meant for a lent machine with CUDA's PyTorch but none of this project's environment, run from the
# repository root with two ignored folders beside the code, made by scripts/device_prepare.sh (docs/performance.md,
# "On a GPU machine"):
#   .whl/  gymnasium's wheels and a lean pybullet source archive (pybullet publishes no wheel for that Python),
#          whose extension modules (pybullet and its eglRenderer plugin) are built there; the built modules are
#          copied to $OUT at once, and a later call that carries them in .whl/built/ skips the build;
#   .gl/   the OpenGL/EGL loader packages (libglvnd), so that PyBullet's EGL plugin finds the NVIDIA driver.
# Every step has its own time limit inside the deadline and writes what it measured to $OUT before the next begins,
# so a step that runs out loses only itself.
set -u
export PYTHONUNBUFFERED=1
out=${OUT:-/tmp/device-check}
mkdir -p "$out"
t0=$(date +%s)
deadline=$((t0 + ${1:-540}))
stamp() { echo "== $(($(date +%s) - t0)) s: $*" | tee -a "$out/steps.log"; }
left() { # seconds for a step: its cap, or what is left before the deadline less a margin
  local l=$((deadline - $(date +%s) - 15))
  ((l < $1)) && echo $((l > 5 ? l : 5)) || echo "$1"
}

for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
if compgen -G ".whl/built/*.so" >/dev/null; then
  cp .whl/built/*.so /tmp/site/
  stamp "pybullet: the modules built by an earlier call"
else
  tar xzf .whl/pybullet-*-lean.tar.gz -C /tmp
  stamp "building pybullet on $(nproc) cores"
  if ! (cd /tmp/pybullet-* && timeout "$(left 300)" python3 setup.py -q build_ext --build-lib /tmp/site \
    >"$out/pybullet_build.log" 2>&1); then
    stamp "pybullet build failed"
    tail -20 "$out/pybullet_build.log"
    exit 1
  fi
  cp /tmp/site/*.so "$out/" 2>/dev/null  # back to this session at once: a rerun carries them in .whl/built/
fi
export PYTHONPATH=/tmp/site:$PWD
stamp "built"
{
  nvidia-smi -L
  python3 -c "import sys, torch, numpy, pandas, pybullet; print(sys.version.split()[0], 'torch', torch.__version__,
    torch.cuda.get_device_name(0), 'numpy', numpy.__version__, 'pandas', pandas.__version__)"
  python3 -c "from omcrl.envs.render import resolve_renderer; print('env.renderer=auto resolves to',
    resolve_renderer('auto'))"
} 2>&1 | tee "$out/machine.txt"

stamp "tests on the GPU (EGL parity, CUDA training, bf16 chain)"
timeout "$(left 150)" python3 -m pytest -q -p no:cacheprovider -x tests/test_envs.py -k "renderer" \
  tests/test_integration.py tests/test_precision.py 2>&1 | tail -15 | tee "$out/tests.txt"

stamp "bench env: tiny vs egl at 64 and 224 px"
timeout "$(left 120)" python3 -m omcrl.bench env --scenes box-v2 --sizes 64,224 --renderers tiny,egl --vec 8 \
  --seconds 6 --out "$out/bench_env.json" 2>&1 | tail -8

stamp "bench pretrain: CUDA fp32 vs bf16, quick and paper shapes"
timeout "$(left 120)" python3 -m omcrl.bench pretrain --device cuda --precision fp32,bf16 --paper-iters 10 \
  --out "$out/bench_pretrain.json" 2>&1 | tail -12

for prec in fp32 bf16; do
  stamp "bench rl: paper preset, $prec"
  timeout "$(left 240)" python3 -m omcrl.bench rl --preset paper --steps 20480 --vec-steps 100 --precision "$prec" \
    --out "$out/bench_rl_$prec.json" 2>&1 | tail -14
done
stamp "done"
