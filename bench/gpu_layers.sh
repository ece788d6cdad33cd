#!/bin/bash
# On a lent GPU machine (issue #35): what each layer of `bench edits`' large scene costs a full-quality frame
# at 1920x1080 while orbiting, by orbiting the scene with one layer removed at a time (`fascicle-bench soak`
# with SOAK_DROP=k; layers 0-5: volume, FA slice, SH glyphs, lines with ROI, splats, tracking). Run after
# bench/gpu_orbit.sh, which unpacks the binary and the loaders and gives the orbit with every layer.
# Usage there: bench/gpu_layers.sh OUT_DIR [FRAMES] [DEADLINE_S]   (defaults 100, 150: runs are cut at it)
set -u
cd "$(dirname "$0")/.."
t0=$(date +%s)
out=$1
deadline=$((t0 + ${3:-150}))
mkdir -p "$out" /tmp/xdg && chmod 700 /tmp/xdg
export XDG_RUNTIME_DIR=/tmp/xdg WGPU_BACKEND=vulkan
if [ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] &&
  ! ls /usr/share/vulkan/icd.d/nvidia* /etc/vulkan/icd.d/nvidia* >/dev/null 2>&1; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
for k in 0 1 2 3 4 5; do
  left=$((deadline - $(date +%s)))
  [ $left -lt 15 ] && echo "drop $k: not started, $left s left" | tee -a "$out/layers.md" && continue
  SOAK_DROP=$k SOAK_SCENE=large SOAK_ORBIT=0.5 SOAK_NO_ROI=1 SOAK_NO_TOGGLE=1 SOAK_NO_CAPTURE=1 timeout $left \
    /tmp/b/fascicle-bench soak --frames "${2:-100}" --size 1920x1080 >"$out/drop$k.log" 2>&1
  echo "drop $k: exit $?, $(grep -h 'dropping\|frame time' "$out/drop$k.log" | tr '\n' ' ')" | tee -a "$out/layers.md"
done
