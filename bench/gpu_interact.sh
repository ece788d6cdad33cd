#!/bin/bash
# On a lent GPU machine without Rust or X (issue #35): `fascicle-bench interact` at 1920x1080 through a real
# window, then the suites of bench/gpu_smoke.sh while time is left, everything in one call.
# Carried from here (ignored folders): .bin/fascicle.xz and .bin/fascicle-bench.xz (release, stripped, xz);
# .gl/*.deb (the Vulkan and GL loaders); .xr/xroot.tar.xz (Debian's Xvfb, xdotool, xkb data and the window's X
# libraries, unpacked into one folder: `dpkg -x` of each package). Outputs go to $OUT/gpu_interact.tgz, refreshed
# every 10 s so that a run cut off still reports.
# NVIDIA's Vulkan driver presents to an X server through its GLX extension, which an Xvfb has only with Mesa's
# software driver beside it (swrast_dri.so and its libraries, LLVM among them: 46 MB xz'd, .mesa/mesa.tar.xz,
# with xdpyinfo to check). That and the binaries exceed the 64 MiB one call carries, so a first call carries
# .mesa and runs `bench/gpu_interact.sh mesa` (unpacked into /tmp/mesa there), a second one, while the machine
# is still warm, the rest.
# Usage there: bench/gpu_interact.sh [INTERACT_TIMEOUT_S] [SMOKE_SUITES] [DEADLINE_S]
#   (defaults 300; volume,splats,tracts,edits,glyphs; 480: no suite starts after it, each is cut at it)
set -u
cd "$(dirname "$0")/.."
t_start=$(date +%s)
if [ "${1:-}" = mesa ]; then
  mkdir -p /tmp/mesa && tar -C /tmp/mesa -xJf .mesa/mesa.tar.xz && cp .mesa/xbin/* /tmp/mesa/ || exit 1
  LD_LIBRARY_PATH=/tmp/mesa/usr/lib/x86_64-linux-gnu ldd /tmp/mesa/usr/lib/x86_64-linux-gnu/dri/swrast_dri.so |
    grep -i "not found"
  echo "mesa unpacked in $(($(date +%s) - t_start)) s"; grep PRETTY /etc/os-release; nvidia-smi -L
  exit 0
fi
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
mesa=/tmp/mesa/usr/lib/x86_64-linux-gnu
LIBGL_DRIVERS_PATH=$mesa/dri LD_LIBRARY_PATH=$LD_LIBRARY_PATH:$mesa:/tmp/xroot/base Xvfb :90 -screen 0 1920x1080x24 -noreset -nolisten tcp -xkbdir /tmp/xroot/usr/share/X11/xkb >$o/xvfb.log 2>&1 &
sleep 2
export DISPLAY=:90
echo "GLX on the display: $(LD_LIBRARY_PATH=$LD_LIBRARY_PATH:$mesa:/tmp/mesa /tmp/mesa/xdpyinfo 2>&1 | grep -c GLX)" |
  tee -a $o/machine.txt
# The viewer alone for 20 s: does a window on this X server get frames from the GPU? First with libglvnd told
# to take NVIDIA's GLX (as GLX windows need here), then without.
if [ -z "${SKIP_PROBE:-}" ]; then
  for vendor in nvidia ""; do
    export __GLX_VENDOR_LIBRARY_NAME=$vendor
    FASCICLE_FRAME_LOG=$o/probe.frames RUST_LOG=info,wgpu_hal=warn timeout 20 fascicle view >$o/probe_$vendor.log 2>&1
    echo "probe (GLX vendor '$vendor'): exit $?, $(wc -l <$o/probe.frames 2>/dev/null || echo 0) frames" |
      tee -a $o/machine.txt
    [ -s $o/probe.frames ] && break
  done
else
  echo skipped >$o/probe.frames
fi
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
deadline=$((t_start + ${3:-480}))
IFS=, read -r -a suites <<<"${2:-volume,splats,tracts,edits,glyphs}"
for suite in "${suites[@]}"; do
  [ "$suite" = none ] && break
  left=$((deadline - $(date +%s)))
  [ $left -lt 15 ] && echo "smoke $suite: not started, $left s left" | tee -a $o/machine.txt && continue
  SMOKE_BENCH=/tmp/b/fascicle-bench SMOKE_ONLY=$suite SMOKE_RUN_TIMEOUT=$left \
    bench/gpu_smoke.sh $o/smoke_$suite >$o/smoke_$suite.out 2>&1
  echo "smoke $suite: exit $? (cut at $left s)" | tee -a $o/machine.txt
  tail -n 1 $o/smoke_$suite/smoke.md >>$o/smoke.md
done
tar -C $o -czf "$OUT/gpu_interact.tgz" .
cat $o/machine.txt $o/smoke.md $o/interact.csv 2>/dev/null
