#!/usr/bin/env bash
# The smoke run on a real GPU (issue #21): every benchmark suite in its full setting (SH glyphs and volume
# rendering at 1920x1080, SMOKE_SIZE=WxH another size) and a 10,000-frame soak of the default scene at 1920x1080,
# one after the other, each a process of its own. It fails when any of them exits with an error or when a log
# shows device loss (wgpu's "device lost", "timed out waiting on the last successful submission", a driver
# reset); the soak itself fails on resident-memory growth over 1 MiB per 10k frames.
# On NVIDIA machines the driver's memory report (nvidia-smi, every 5 s) is sampled beside each run.
#
# Usage: bench/gpu_smoke.sh [OUT_DIR]   (default target/gpu-smoke); logs, CSVs and smoke.md land there.
# Checks of the script itself: SMOKE_QUICK=1 runs each suite with --quick, SMOKE_ONLY=soak,glyphs only those runs,
# SMOKE_SOAK_FRAMES=N and SMOKE_SOAK_SIZE=WxH a shorter soak. SMOKE_ONLY also sets the order of the runs.
# On a machine without Rust (a lent GPU): SMOKE_BENCH=PATH runs that prebuilt fascicle-bench (built and carried from
# here) instead of building; SMOKE_RUN_TIMEOUT=S stops any one run after S seconds (exit 124 in its row).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-target/gpu-smoke}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/fascicle/target}"
if [ -n "${SMOKE_BENCH:-}" ]; then
  bench=("$SMOKE_BENCH")
  export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
  if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
    export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/fascicle-runtime-$(id -u)"
    mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
  fi
else
  ./run bench --help >/dev/null # builds fascicle and fascicle-bench once, installs what the suites need
  bench=(./run bench)           # ./run picks the adapter as for every other command
fi
limit=()
[ -n "${SMOKE_RUN_TIMEOUT:-}" ] && limit=(timeout "$SMOKE_RUN_TIMEOUT")
quick=()
size=(--size "${SMOKE_SIZE:-1920x1080}")
[ "${SMOKE_QUICK:-0}" = 1 ] && quick=(--quick) && size=()

# name and arguments of each run
runs=(
  "splats|splats ${quick[*]} --csv $out/splats.csv"
  "glyphs|glyphs ${quick[*]} ${size[*]} --csv $out/glyphs.csv"
  "volume|volume ${quick[*]} ${size[*]} --csv $out/volume.csv"
  "tracts|tracts ${quick[*]} --csv $out/tracts.csv"
  "edits|edits ${quick[*]} --csv $out/edits.csv"
  "soak|soak --frames ${SMOKE_SOAK_FRAMES:-10000} --size ${SMOKE_SOAK_SIZE:-1920x1080} --csv $out/soak.csv"
)

{
  echo "# GPU smoke run, $(date -u +%Y-%m-%dT%H:%MZ)"
  echo
  echo "adapter: $(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null \
    || echo "no nvidia-smi here: the adapter each run used is in its log")"
  echo
  echo "| run | exit | wall (s) | device loss in log | GPU memory used, MiB (min-max) |"
  echo "|---|---|---|---|---|"
} >"$out/smoke.md"

# SMOKE_ONLY: these runs, in this order
if [ -n "${SMOKE_ONLY:-}" ]; then
  chosen=()
  IFS=, read -r -a names <<<"$SMOKE_ONLY"
  for want in "${names[@]}"; do
    for entry in "${runs[@]}"; do
      [ "${entry%%|*}" = "$want" ] && chosen+=("$entry")
    done
  done
  runs=("${chosen[@]}")
fi

failed=0
for entry in "${runs[@]}"; do
  name="${entry%%|*}"
  read -r -a args <<<"${entry#*|}"
  mem="$out/$name.gpu_mem.csv"
  sampler=""
  if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -l 5 >"$mem" 2>/dev/null &
    sampler=$!
  fi
  start=$(date +%s)
  set +e
  "${limit[@]}" "${bench[@]}" "${args[@]}" >"$out/$name.log" 2>&1
  code=$?
  set -e
  wall=$(($(date +%s) - start))
  [ -n "$sampler" ] && kill "$sampler" 2>/dev/null && wait "$sampler" 2>/dev/null || true
  lost=no
  if grep -qiE 'device lost|timed out waiting|DeviceLost|Xid|GPU has fallen off' "$out/$name.log"; then
    lost=yes
  fi
  range="-"
  if [ -s "$mem" ]; then
    range=$(sort -n "$mem" | sed -n '1p;$p' | paste -sd- -)
  fi
  echo "| $name | $code | $wall | $lost | $range |" >>"$out/smoke.md"
  if [ "$code" != 0 ] || [ "$lost" = yes ]; then
    failed=1
    echo "FAILED: $name (exit $code, device loss: $lost); last lines of $out/$name.log:" >&2
    tail -n 20 "$out/$name.log" >&2
  fi
done
cat "$out/smoke.md"
exit "$failed"
