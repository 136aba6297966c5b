#!/usr/bin/env bash
# Everything a borrowed GPU session should measure, in one command, with every log kept.
#
#   bash benchmarks/gpu_session.sh OUTDIR          # on the GPU machine: CUDA tests + the three benchmarks
#   DEVICE=cpu SMALL=1 bash benchmarks/gpu_session.sh /tmp/dry   # dry run of the same steps on a CPU
#   STEPS="tests semantic" bash benchmarks/gpu_session.sh OUTDIR  # only these steps (a short lease)
#   BASELINE=.ab/base bash benchmarks/gpu_session.sh OUTDIR      # also semantic_ab against a revision laid
#                                          # out beforehand by `benchmarks/semantic_ab.py prepare REV .ab/base`
#
# Steps (each one's log goes to OUTDIR/<step>.log; a failing step does not stop the others):
#   tests      the kernel, semantic and mapping tests (they run on cuda when torch sees a GPU); first the
#              warp-culling pieces (ballot, warp rectangles), which only a GPU runs with 32 lanes
#   rasterize  ours vs gsplat, forward and forward+backward, 50k..2M Gaussians at 1200x680 (issue #2)
#   semantic   semantic render + contribution vs a colour forward pass, 500k at 1200x680 (issue #3)
#   mapping    per-keyframe module times at 1200x680 with ~1M Gaussians (issue #5), also as JSON
#   profile    kernel-level tables of the three (OUTDIR/profile/): device-kernel vs wall time per call
#   semantic_ab with BASELINE: the semantic call of this tree and of the baseline in turn, same machine
# OUTDIR/summary.txt lists each step's exit status and wall time; the script exits 1 when any step failed.
set -uo pipefail
out=${1:?usage: gpu_session.sh OUTDIR}
device=${DEVICE:-cuda}
steps=" ${STEPS:-tests rasterize semantic mapping profile semantic_ab} "
# absolute before the cd below, so that a relative OUTDIR means the caller's directory
out=$(mkdir -p "$out" && cd "$out" && pwd) || exit 2
cd "$(dirname "$0")/.."
failed=0

if [[ "${SMALL:-0}" == 1 ]]; then
  size=160x120; w=160; h=120; counts=5k; sem_counts=5k; gaussians=20000; iters=2
else
  size=1200x680; w=1200; h=680; counts=50k,200k,500k,1M,2M; sem_counts=500k; gaussians=1000000; iters=20
  # gsplat compiles its CUDA extension on first use (~90 s): use every core
  export MAX_JOBS=${MAX_JOBS:-$(nproc)}
fi

: > "$out/summary.txt"
step() {
  local name=$1; shift
  [[ "$steps" == *" $name "* ]] || return 0
  local t0=$SECONDS
  "$@" > "$out/$name.log" 2>&1
  local rc=$?
  (( rc == 0 )) || failed=1
  printf '%-10s rc=%-3s %5ss  %s\n' "$name" "$rc" "$((SECONDS - t0))" "$*" | tee -a "$out/summary.txt"
}

python - > "$out/environment.txt" 2>&1 <<'PY'
import platform, torch, warp as wp
wp.config.quiet = True
wp.init()
print("python", platform.python_version(), "torch", torch.__version__, "warp", wp.__version__)
print("cuda", torch.cuda.is_available(), torch.cuda.get_device_name(0) if torch.cuda.is_available() else "-")
try:
    import gsplat
    print("gsplat", gsplat.__version__)
except ImportError as e:
    print("gsplat not importable:", e)
PY

step tests python -m pytest -q -p no:cacheprovider tests/kernels/test_blend_culling.py \
  tests/rendering/test_projection.py tests/rendering/test_rasterization.py \
  tests/rendering/test_rasterization_edges.py tests/rendering/test_semantics.py tests/mapping/test_neighbors.py \
  tests/test_gaussians.py tests/mapping/test_local.py tests/mapping/test_refine.py \
  tests/mapping/test_longterm.py tests/mapping/test_merge.py tests/mapping/test_optimize.py tests/mapping/test_mapper.py
step rasterize python benchmarks/rasterize.py --device "$device" --width "$w" --height "$h" \
  --counts "$counts" --iters "$iters"
step semantic python benchmarks/semantic.py --device "$device" --width "$w" --height "$h" \
  --counts "$sem_counts" --iters "$iters"
step mapping python benchmarks/mapping.py modules --device "$device" --size "$size" \
  --gaussians "$gaussians" --json "$out/mapping_modules.json"
step profile python benchmarks/kernel_profile.py --device "$device" --width "$w" --height "$h" \
  --gaussians "$sem_counts" --map-gaussians "$gaussians" --out "$out/profile"
if [[ -n "${BASELINE:-}" ]]; then
  step semantic_ab python benchmarks/semantic_ab.py run "$BASELINE" --device "$device" --width "$w" \
    --height "$h" --counts "$sem_counts" --iters "$iters"
fi
exit "$failed"
