#!/bin/bash
# On a lent GPU machine without Rust or X (issue #35): `fascicle-bench interact` at 1920x1080 through a real
# window, then the short suites of bench/gpu_smoke.sh, everything in one call.
# Carried from here (ignored folders): .bin/fascicle.xz and .bin/fascicle-bench.xz (release, stripped, xz);
# .gl/*.deb (the Vulkan and GL loaders); .xr/xroot.tar.xz (Debian's Xvfb, xdotool, xkb data and the window's X
# libraries, unpacked into one folder: `dpkg -x` of each package). Outputs go to $OUT/gpu_interact.tgz, refreshed
# every 10 s so that a run cut off still reports.
# Tried on an H200 (2026-11-27): Xvfb starts and the viewer opens its window, but NVIDIA's Vulkan driver presents
# through the X server's GLX extension, which an Xvfb has only with Mesa's GLX and software driver beside it
# (libglx-mesa0, libgl1-mesa-dri and LLVM, 37 MB): without them the viewer dies after its first frame. Carry
# them in a first call (unpacked into /tmp there) and the rest in a second while the machine is warm: one call
# carries at most 64 MiB.
# Usage there: bench/gpu_interact.sh [INTERACT_TIMEOUT_S] [SMOKE_SUITES]   (defaults 300, edits,splats,tracts,volume)
set -u
cd "$(dirname "$0")/.."
o=/tmp/gpu_interact
mkdir -p $o /tmp/b /tmp/xroot /tmp/xdg && chmod 700 /tmp/xdg
( while sleep 10; do tar -C $o -czf "$OUT/gpu_interact.tgz" . 2>/dev/null; done ) >/dev/null 2>&1 &
saver=$!
trap 'kill $saver 2>/dev/null' EXIT
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
tar -C /tmp/xroot -xJf .xr/xroot.tar.xz
xz -dc .bin/fascicle-bench.xz >/tmp/b/fascicle-bench
xz -dc .bin/fascicle.xz >/tmp/b/fascicle
chmod +x /tmp/b/*
# The X libraries for every program here; the system libraries Xvfb needs besides (xroot/base) for Xvfb alone.
export LD_LIBRARY_PATH=/tmp/xroot/usr/lib/x86_64-linux-gnu:/tmp/xroot/lib/x86_64-linux-gnu PATH=/tmp/b:$PATH:/tmp/xroot/usr/bin
export XDG_RUNTIME_DIR=/tmp/xdg WGPU_BACKEND=vulkan XKB_CONFIG_ROOT=/tmp/xroot/usr/share/X11/xkb
# Xvfb runs the keymap compiler from the path it was built with.
[ -e /usr/bin/xkbcomp ] || ln -s /tmp/xroot/usr/bin/xkbcomp /usr/bin/xkbcomp
if [ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] &&
  ! ls /usr/share/vulkan/icd.d/nvidia* /etc/vulkan/icd.d/nvidia* >/dev/null 2>&1; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader; nproc; uname -r; } >$o/machine.txt 2>&1
LD_LIBRARY_PATH=$LD_LIBRARY_PATH:/tmp/xroot/base Xvfb :90 -screen 0 1920x1080x24 -noreset -nolisten tcp -xkbdir /tmp/xroot/usr/share/X11/xkb >$o/xvfb.log 2>&1 &
sleep 2
export DISPLAY=:90
# The viewer alone for 25 s: does a window on this X server get frames from the GPU?
[ -z "${SKIP_PROBE:-}" ] && FASCICLE_FRAME_LOG=$o/probe.frames RUST_LOG=info,wgpu_hal=warn timeout 25 fascicle view >$o/probe.log 2>&1
echo "probe: exit $?, $(wc -l <$o/probe.frames 2>/dev/null || echo 0) frames" | tee -a $o/machine.txt
[ -n "${SKIP_PROBE:-}" ] && echo skipped >$o/probe.frames
if [ -s $o/probe.frames ]; then
  nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -l 5 >$o/interact.gpu_mem.csv 2>/dev/null &
  mem=$!
  timeout "${1:-300}" fascicle-bench interact --scenes "${INTERACT_SCENES:-default,large}" --size 1920x1080 --move-ms 3 \
    --settle-timeout 150 --csv $o/interact.csv >$o/interact.log 2>&1
  echo "interact: exit $?" | tee -a $o/machine.txt
  kill $mem
  cp /tmp/fascicle-interact-*/*.frames /tmp/fascicle-interact-*/*.log $o/ 2>/dev/null
fi
pkill Xvfb
[ "${2:-}" = none ] || SMOKE_BENCH=/tmp/b/fascicle-bench SMOKE_ONLY="${2:-edits,splats,tracts,volume}" SMOKE_RUN_TIMEOUT=100 \
  bench/gpu_smoke.sh $o/smoke >$o/smoke.out 2>&1
echo "smoke: exit $?" | tee -a $o/machine.txt
tar -C $o -czf "$OUT/gpu_interact.tgz" .
cat $o/machine.txt $o/smoke/smoke.md
