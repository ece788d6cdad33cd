#!/usr/bin/env python3
"""Times what the viewer shows on the screen after `fascicle view FILE` (a tractogram, an image or a scene).

Starts the viewer on a fresh Xvfb display (1280x800, the window's default 1280x720 inside it), grabs the screen
every 250 ms and samples the process's resident memory from /proc, and prints, in seconds after the launch:
- `streamlines`: the first grab whose 3D view (right of the panel) holds coloured pixels;
- `complete`: the last grab that differed from the one before (the picture stops changing there);
- the peak resident memory, and its anonymous and file-backed parts at that peak.
The last grab is written to /tmp/view_time.png. The viewer's frame log says when a frame's update ran, not when
lavapipe finished drawing it (seconds later at 1M streamlines): this script times the screen.

Needs Xvfb and Pillow (`pip install pillow`), and a release build of the viewer.
Usage: bench/view_time.py FILE [SECONDS=40] [VIEWER=$CARGO_TARGET_DIR/release/fascicle]
"""

import hashlib
import os
import subprocess
import sys
import time

from PIL import ImageGrab


def rss_kib(pid):
    """VmRSS, RssAnon and RssFile of the process in KiB, or None once it has exited."""
    try:
        with open(f"/proc/{pid}/status") as f:
            fields = dict(line.split(":", 1) for line in f if ":" in line)
    except FileNotFoundError:
        return None
    return tuple(int(fields.get(k, "0 kB").split()[0]) for k in ("VmRSS", "RssAnon", "RssFile"))


def coloured(img):
    """Pixels of the 3D view (right of the panel) with a saturated colour, on a 145x175 thumbnail."""
    right = img.crop((700, 0, 1280, 700)).resize((145, 175))
    return sum(1 for p in right.getdata() if max(p[:3]) - min(p[:3]) > 60)


def main():
    path = sys.argv[1]
    limit = float(sys.argv[2]) if len(sys.argv) > 2 else 40.0
    target = os.environ.get("CARGO_TARGET_DIR", os.path.expanduser("~/.cache/fascicle/target"))
    viewer = sys.argv[3] if len(sys.argv) > 3 else os.path.join(target, "release", "fascicle")
    display = next(f":{n}" for n in range(150, 250) if not os.path.exists(f"/tmp/.X11-unix/X{n}"))
    xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while not os.path.exists(f"/tmp/.X11-unix/X{display[1:]}"):
            time.sleep(0.05)
        # The socket comes before the server answers: a viewer started then finds no display and exits.
        for _ in range(100):
            try:
                ImageGrab.grab(xdisplay=display)
                break
            except OSError:
                time.sleep(0.05)
        t0 = time.time()
        proc = subprocess.Popen([viewer, "view", path], env=dict(os.environ, DISPLAY=display),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        last, complete, streams, peak, img = None, None, None, (0, 0, 0), None
        while time.time() - t0 < limit and proc.poll() is None:
            mem = rss_kib(proc.pid)
            if mem and mem[0] > peak[0]:
                peak = mem
            img = ImageGrab.grab(xdisplay=display)
            h = hashlib.md5(img.tobytes()).hexdigest()
            if h != last:
                last, complete = h, time.time() - t0
                if streams is None and coloured(img) > 200:
                    streams = complete
            time.sleep(0.25)
        proc.kill()
        if img is not None:
            img.save("/tmp/view_time.png")
        gib = 1024 * 1024
        first = "never" if streams is None else f"{streams:.1f} s"
        print(f"{os.path.basename(path)}: streamlines {first}, complete {complete:.1f} s, peak resident "
              f"{peak[0] / gib:.2f} GiB (anonymous {peak[1] / gib:.2f}, file-backed {peak[2] / gib:.2f})")
    finally:
        xvfb.kill()


if __name__ == "__main__":
    main()
