#!/bin/bash
# On a lent GPU machine without a display that can present (issue #35): the orbit and ROI-drag rows of
# `bench interact` drawn headless at 1920x1080 by `fascicle-bench soak` (SOAK_ORBIT, SOAK_ROI_EVERY), every
# frame at full quality and waited for, on the default scene and on `bench edits`' large scene.
# Carried from here: .bin/fascicle-bench.xz (release, stripped) and .gl/*.deb (the Vulkan loader).
# With SOAK_BUDGET=1 in the environment the frames follow the frame budget as in the viewer (bench/src/soak.rs).
# Usage there: bench/gpu_orbit.sh [SIZE] [DEADLINE_S]   (defaults 1920x1080, 200: runs are cut at it)
set -u
cd "$(dirname "$0")/.."
t0=$(date +%s)
size=${1:-1920x1080}
deadline=$((t0 + ${2:-200}))
mkdir -p /tmp/b /tmp/xdg && chmod 700 /tmp/xdg
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
xz -dc .bin/fascicle-bench.xz >/tmp/b/fascicle-bench && chmod +x /tmp/b/fascicle-bench
export XDG_RUNTIME_DIR=/tmp/xdg WGPU_BACKEND=vulkan
if [ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] &&
  ! ls /usr/share/vulkan/icd.d/nvidia* /etc/vulkan/icd.d/nvidia* >/dev/null 2>&1; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
fi
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>&1 | tee $OUT/orbit.md
# name, frames, environment of each run
for run in "default_orbit 600 SOAK_ORBIT=0.5 SOAK_NO_ROI=1" "default_roi_drag 300 SOAK_ROI_EVERY=1" \
  "large_orbit 300 SOAK_ORBIT=0.5 SOAK_NO_ROI=1 SOAK_SCENE=large" "large_roi_drag 200 SOAK_ROI_EVERY=1 SOAK_SCENE=large"; do
  read -r name frames vars <<<"$run"
  left=$((deadline - $(date +%s)))
  [ $left -lt 10 ] && echo "$name: not started, $left s left" | tee -a $OUT/orbit.md && continue
  env SOAK_NO_TOGGLE=1 SOAK_NO_CAPTURE=1 $vars timeout $left /tmp/b/fascicle-bench soak --frames $frames --size $size \
    >$OUT/$name.log 2>&1
  echo "$name: exit $?, $(grep -h 'frame time\|frame budget' $OUT/$name.log | tr '\n' ' ')" | tee -a $OUT/orbit.md
done
