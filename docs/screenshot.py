"""Screenshot a Rerun recording in the native viewer, headless (for the pictures in these docs).

    .venv/bin/icefloe viz run.mcap --save run.rrd                  # a recording, as viz draws it
    .venv/bin/python docs/screenshot.py run.rrd shot.png --before-end 2

Spawns the viewer of the installed rerun-sdk with ``--headless`` (on a machine without a GPU it
renders with Mesa's software Vulkan, lavapipe: Debian's ``mesa-vulkan-drivers``), opens the file
with its default blueprint, puts the time cursor ``--before-end`` seconds before the end of the
``stamp`` timeline, paused, waits for it to load and settle, and saves the picture. A software
renderer on a busy machine may miss the viewer's 15 s deadline for a frame: it is asked again.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from rerun.experimental import ViewerClient

TIMELINE = "stamp"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("rrd", help="the recording (.rrd)")
    p.add_argument("png", help="where to save the picture")
    p.add_argument("--before-end", type=float, default=2.0, metavar="S",
                   help=f"time cursor this long before the end of the {TIMELINE} timeline (default 2 s)")
    p.add_argument("--port", type=int, default=9877, help="the viewer's port (default 9877)")
    p.add_argument("--tries", type=int, default=8, help="ask for the frame this many times at most")
    p.add_argument("--settle", type=float, default=15.0, metavar="S",
                   help="wait this long after loading before the picture (default 15 s)")
    args = p.parse_args()
    viewer = ViewerClient.spawn(headless=True, port=args.port,
                                executable_path=str(Path(sys.executable).parent / "rerun"))
    try:
        viewer.open(str(Path(args.rrd).resolve()))
        recording = viewer.get_state().recordings[0]
        end = next(t.end for t in recording.timelines if t.name == TIMELINE)
        cursor = np.datetime64(end - int(args.before_end * 1e9), "ns")
        viewer.set_time(TIMELINE, timestamp=cursor, play_state="paused")
        deadline = time.monotonic() + 120
        while viewer.get_state().loading and time.monotonic() < deadline:
            time.sleep(1.0)
        time.sleep(args.settle)  # chunks fetched on demand, the start-up notices gone
        for attempt in range(1, args.tries + 1):
            try:
                viewer.save_screenshot(str(Path(args.png).resolve()))
                print(f"saved {args.png} (try {attempt})")
                return
            except TimeoutError:
                continue
        raise SystemExit(f"the viewer did not render a frame in {args.tries} tries")
    finally:
        viewer.quit()


if __name__ == "__main__":
    main()
