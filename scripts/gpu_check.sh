#!/usr/bin/env bash
# The GPU backend's checks in one short run (issue 11, item 5), for a machine with CuPy and a CUDA
# device but no package registry: the lent device machine (docs: README, "GPU backend").  It uses the
# machine's own python3 and packages (numpy, scipy, h5py, click, pyyaml, matplotlib, threadpoolctl,
# xxhash, CuPy, pytest, hypothesis) with this checkout on PYTHONPATH.  What that machine lacks
# (ducc0, the image's fused range oversampling) travels as wheels in .whl/ (git-ignored), fetched here
# for its Python (3.12) and installed there into a scratch folder, nothing into its own environment:
#
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 -d .whl ducc0==0.42.0
#   bash scripts/gpu_check.sh [OUT_DIR]        (default: $OUT, else gpu_check/; the device tool: carry .whl)
#
# Writes to OUT_DIR: versions.txt (python, numpy, scipy, CuPy, the device), gpu_tests.log (the GPU
# tests: with a device none of the CuPy tests may skip), gpu_bench.json (`fwdlook bench --backend gpu
# --json`: the three GPU stages against one device fft2, their agreement with the CPU stages, the
# whole chains on both backends), and rc.txt (each step's exit status, and why a step could not run).
# The tests are cut at 240 s and the bench at 240 s, so that the whole stays inside one 600 s command
# with the installs; with FWDLOOK_XP=numpy (the GPU code on the host) the script took 15-26 s on this
# project's 2 cores.  A CuPy test skipped for want of CuPy or a device, where the versions step found
# one, fails the tests step (the tests of the no-GPU refusals skip on a GPU machine, rightly).
set -uo pipefail
out=$(realpath -m "${1:-${OUT:-gpu_check}}")     # absolute: the steps below run from the checkout
mkdir -p "$out"
here=$(cd "$(dirname "$0")/.." && pwd)
export PYTHONPATH="$here${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1
py=${PYTHON:-python3}
cd "$here" || exit 2
stop() {                                          # a step that cannot run: said in rc.txt, not lost
  printf 'stopped: %s\n' "$1" | tee "$out/rc.txt"
  exit 2
}
if compgen -G ".whl/*.whl" >/dev/null; then      # the carried wheels, into a scratch site folder
  site=$(mktemp -d)
  "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" .whl/*.whl \
    >"$out/pip.log" 2>&1 || stop "pip could not install .whl/*.whl (pip.log)"
  export PYTHONPATH="$PYTHONPATH:$site"
fi
"$py" -c "import ducc0" 2>/dev/null || stop "ducc0 cannot be imported: carry its wheel in .whl/ (this script's header)"

{
  "$py" - <<'EOF'
import platform, numpy, scipy
print("python", platform.python_version(), "numpy", numpy.__version__, "scipy", scipy.__version__)
try:
    import cupy
    props = cupy.cuda.runtime.getDeviceProperties(0)
    name = props["name"]
    print("cupy", cupy.__version__, "devices", cupy.cuda.runtime.getDeviceCount(),
          name.decode() if isinstance(name, bytes) else name, "runtime", cupy.cuda.runtime.runtimeGetVersion())
except Exception as exc:  # noqa: BLE001  (reported, the steps below then skip or exit 2)
    print("cupy unusable:", type(exc).__name__, exc)
EOF
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.mem --format=csv 2>&1 || true
} >"$out/versions.txt" 2>&1
cat "$out/versions.txt"

# the GPU tests (the CuPy ones skip without a device: -rs lists every skip and why)
timeout 240 "$py" -m pytest -q -rs -p no:cacheprovider tests/test_gpu_backend.py >"$out/gpu_tests.log" 2>&1
tests_rc=$?
if grep -q '^cupy .* devices [1-9]' "$out/versions.txt" && grep -qiE "^SKIPPED.*(cupy|cuda)" "$out/gpu_tests.log"; then
  echo "a CuPy test skipped on a machine with CuPy and a device (above)" >>"$out/gpu_tests.log"
  [ "$tests_rc" -eq 0 ] && tests_rc=3
fi
tail -n 15 "$out/gpu_tests.log"

# the device figures for the README
timeout 240 "$py" -m fwdlook_cli.cli bench --backend gpu --json >"$out/gpu_bench.json" 2>"$out/gpu_bench.err"
bench_rc=$?
tail -n 3 "$out/gpu_bench.err"
printf 'gpu_tests %s\ngpu_bench %s\n' "$tests_rc" "$bench_rc" | tee "$out/rc.txt"
[ "$tests_rc" -eq 0 ] && [ "$bench_rc" -eq 0 ]
