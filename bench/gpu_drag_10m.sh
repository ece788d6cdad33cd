#!/bin/bash
# On a lent GPU machine without Rust (issue #33): release binaries carried in .bin/ as for bench/gpu_scale_10m.sh.
# ROI drag steps on 1M and 10M .tck files read in place (fascicle-bench scale --drag-mapped), peak memory polled.
set -u
mkdir -p /tmp/b /tmp/xdg; chmod 700 /tmp/xdg
xz -dc .bin/fascicle-bench.xz > /tmp/b/fascicle-bench; xz -dc .bin/fascicle.xz > /tmp/b/fascicle; chmod +x /tmp/b/*
nproc; free -g | head -2
t0=$(date +%s)
( /tmp/b/fascicle-bench scale --write-only --sizes 10000000 --dir /tmp/sc > $OUT/write10m.log 2>&1 ) & W=$!
while [ ! -e /tmp/sc/brain10000000.trk ] && kill -0 $W 2>/dev/null && [ $(( $(date +%s) - t0 )) -lt 200 ]; do sleep 1; done
kill $W 2>/dev/null; sleep 1; pkill -f "write-only"; echo "10M tck written in $(( $(date +%s) - t0 )) s"
rm -f /tmp/sc/*.trk /tmp/sc/*.trx*
for f in 1000000 10000000; do
  [ $f = 1000000 ] && /tmp/b/fascicle-bench scale --write-only --sizes 1000000 --dir /tmp/sc1 > /dev/null 2>&1 && F=/tmp/sc1/brain1000000.tck || F=/tmp/sc/brain10000000.tck
  cat $F > /dev/null
  t=$(date +%s.%N); /tmp/b/fascicle-bench scale --drag-mapped $F > $OUT/drag_$f.txt 2>&1 & p=$!; hwm=0
  while kill -0 $p 2>/dev/null; do h=$(awk '/VmHWM/{print $2}' /proc/$p/status 2>/dev/null); [ -n "$h" ] && [ "$h" -gt "$hwm" ] && hwm=$h; sleep 0.1; done
  echo "$f: $(cat $OUT/drag_$f.txt) wall $(awk "BEGIN{print $(date +%s.%N) - $t}") s peak $((hwm/1024)) MiB"
done
