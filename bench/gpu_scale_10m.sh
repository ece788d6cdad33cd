#!/bin/bash
# On a lent GPU machine without Rust (issue #33): release binaries built here are carried xz-compressed in .bin/
# (fascicle.xz, fascicle-bench.xz) with the Vulkan loader debs in .gl/; run from the repository root there, $OUT
# collecting the files. 1M bench scale rows, then the 10M .tck written there and rendered at 1920x1080, info, select.
set -u
R=$(pwd); mkdir -p /tmp/gl /tmp/b /tmp/xdg; chmod 700 /tmp/xdg
for d in .gl/*.deb; do dpkg -x $d /tmp/gl; done
export LD_LIBRARY_PATH=/tmp/gl/usr/lib/x86_64-linux-gnu XDG_RUNTIME_DIR=/tmp/xdg WGPU_BACKEND=vulkan
xz -dc .bin/fascicle.xz > /tmp/b/fascicle; xz -dc .bin/fascicle-bench.xz > /tmp/b/fascicle-bench; chmod +x /tmp/b/*
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader > $OUT/gpu.txt 2>&1
nproc >> $OUT/gpu.txt; free -g >> $OUT/gpu.txt
peak() { # run a command, print wall s and peak RSS MiB
  local t0=$(date +%s.%N); "$@" & local p=$!; local hwm=0
  while kill -0 $p 2>/dev/null; do h=$(awk '/VmHWM/{print $2}' /proc/$p/status 2>/dev/null); [ -n "$h" ] && [ "$h" -gt "$hwm" ] && hwm=$h; sleep 0.05; done
  wait $p; local rc=$?; echo "rc $rc wall $(awk "BEGIN{print $(date +%s.%N) - $t0}") s peak $((hwm/1024)) MiB: $*"
}
cd /tmp
timeout 150 /tmp/b/fascicle-bench scale --sizes 1000000 --dir /tmp/sc --csv $OUT/h200_scale_1m.csv > $OUT/scale_1m.log 2>&1; echo "scale rc $?"
tail -14 $OUT/scale_1m.log
for s in 1280x720 1920x1080; do
cat > /tmp/1m.ron <<R
(layers: [ ( name: "t", visible: true, opacity: 1.0, kind: Tractogram(path: "/tmp/sc/brain1000000.tck") ) ],
 camera: ( eye: (0.0, -330.0, 60.0), target: (0.0, 0.0, 0.0), up: (0.0, 0.0, 1.0), fov_y_deg: 45.0 ))
R
peak /tmp/b/fascicle render /tmp/1m.ron --out $OUT/render_1m_$s.png --size $s --force -q
done
rm -f /tmp/sc/*.trk /tmp/sc/*.trx /tmp/sc/converted* /tmp/sc/selected*
( /tmp/b/fascicle-bench scale --write-only --sizes 10000000 --dir /tmp/sc > $OUT/write10m.log 2>&1 ) & W=$!
t0=$(date +%s); while [ ! -e /tmp/sc/brain10000000.trk ] && kill -0 $W 2>/dev/null && [ $(( $(date +%s) - t0 )) -lt 200 ]; do sleep 1; done
kill $W 2>/dev/null; sleep 1; pkill -f "write-only" ; echo "10M tck written in $(( $(date +%s) - t0 )) s"; ls -la /tmp/sc
sed 's/1000000/10000000/' /tmp/1m.ron > /tmp/10m.ron
peak /tmp/b/fascicle render /tmp/10m.ron --out $OUT/render_10m_1920x1080.png --size 1920x1080 --force -q
RUST_LOG=warn,fascicle_render=debug /tmp/b/fascicle render /tmp/10m.ron --out $OUT/render_10m_b.png --size 1920x1080 --force -q > $OUT/render_10m_debug.log 2>&1
tail -5 $OUT/render_10m_debug.log
peak /tmp/b/fascicle info --json /tmp/sc/brain10000000.tck
peak /tmp/b/fascicle select /tmp/sc/brain10000000.tck --include 0,0,0,10 --out /tmp/sc/sel10m.tck --force -q
