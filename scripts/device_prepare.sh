#!/usr/bin/env bash
# Make the two ignored folders scripts/device_check.sh needs on a lent GPU machine that has CUDA's PyTorch for
# Python 3.12 but none of this project's packages and no network:
#   .whl/  gymnasium's wheels, and pybullet's source archive made lean: pybullet publishes no wheel for Python 3.12,
#          so the check builds its two extension modules there. Its bundled data and gym examples (190 MB) are left
#          out (the kit uses neither), so the archive fits the 64 MiB a call may carry beside the repository, and
#          its compile runs at most PB_JOBS jobs at once (default 8; setup.py would start two per core, bounded by
#          the memory `free` reports, which on such a machine starts small and grows on demand);
#   .gl/   the OpenGL/EGL loader packages (libglvnd) that PyBullet's EGL plugin needs to reach the NVIDIA driver.
# Run from the repository root on a machine with pip and apt-get; both folders are listed in .git/info/exclude.
set -euo pipefail
jobs=${PB_JOBS:-8}
mkdir -p .git/info .whl .gl
for d in /.whl/ /.gl/; do grep -qxF "$d" .git/info/exclude 2>/dev/null || echo "$d" >>.git/info/exclude; done

python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  -d .whl gymnasium==1.4.0 farama-notifications==0.0.6

tmp=$(mktemp -d)
python3 -m pip download -q --no-deps --no-binary=:all: -d "$tmp" pybullet==3.2.7
tar xzf "$tmp"/pybullet-3.2.7.tar.gz -C "$tmp"
src="$tmp/pybullet-3.2.7"
find "$src/examples/pybullet/gym/pybullet_data" -type f ! -name '__init__.py' -delete
rm -rf "$src/examples/pybullet/gym/pybullet_envs" "$src/examples/pybullet/gym/pybullet_examples" \
  "$src/examples/Benchmarks"
sed -i "s/^  N = 2 \* multiprocessing.cpu_count()  # number of parallel compilations$/  N = $jobs/" "$src/setup.py"
sed -i 's/^    N = min(mem, N)$/    N = min(N, '"$jobs"')/' "$src/setup.py"
grep -q "N = $jobs" "$src/setup.py" || { echo "device_prepare: pybullet's setup.py changed; set its job count by hand" >&2; exit 1; }
tar czf .whl/pybullet-3.2.7-lean.tar.gz -C "$tmp" pybullet-3.2.7
rm -rf "$tmp"

lists=$(mktemp -d)
o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists="$lists")
mkdir -p "$lists/partial"
apt-get "${o[@]}" update >/dev/null
(cd .gl && apt-get "${o[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
du -sh .whl .gl
