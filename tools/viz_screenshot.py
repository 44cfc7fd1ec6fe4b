"""Regenerate the README's screenshot (docs/viz-screenshot.png): the viewer's default blueprint on a
recording of the real simulated stack while a program drives it.

    .venv/bin/python tools/viz_screenshot.py                      # about a minute
    .venv/bin/python tools/viz_screenshot.py --out /tmp/shot.png --keep /tmp/run.rrd

1. A robot of its own (the shipped ``sim`` on a free port, in a temporary folder): its router, then
   viz recording it (``--save``), and only then the services, so their start-up lines are in the log.
2. A `Robot` drives a loop past the lab's markers, shows text on the screen, and sends one bad
   command, which hwbridge rejects with a log line (the log panel has something to show).
3. The recording is opened in a headless native viewer (Mesa's software Vulkan, lavapipe, where
   there is no GPU: ``apt-get install mesa-vulkan-drivers``), paused 2 s before its end, and the
   viewer saves the screenshot (1920x1080).
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from icefloe import config as config_mod
from icefloe.client import Robot
from icefloe.runtime import raw_session
from icefloe.schemas import keys
from icefloe.services.viz import viewer
from icefloe.services.viz.logging_rr import TIMELINE
from icefloe.services.viz.readback import read_rrd

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "viz-screenshot.png"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(module: str, config: Path, *args: str, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as out:
        return subprocess.Popen([sys.executable, "-m", module, "--config", str(config), *args], stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)


def wait(what: str, ready, timeout: float = 60.0) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not ready():
        if time.monotonic() > deadline:
            raise SystemExit(f"viz_screenshot: {what} not ready within {timeout:.0f} s")
        time.sleep(0.2)


def stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for proc in reversed(procs):
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in reversed(procs):
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


def drive(robot: Robot) -> None:
    """A loop past the markers: forward, a left turn, forward, a curve back; and a few things to log."""
    robot.print_oled("icefloe\nfirst hour")
    robot.leds[2] = True
    quarter = math.pi / 2 * 0.156 / 2 / 0.1  # s at 0.1 m/s per wheel for a quarter turn on the spot
    robot.set_velocity(0.15, 0.15, duration=3.0, accel=0.3)
    robot.set_velocity(-0.1, 0.1, duration=quarter)
    robot.set_velocity(0.15, 0.15, duration=2.5, accel=0.3)
    robot.reset_pose(robot.pose.x, robot.pose.y, robot.pose.theta)  # odometry logs the reset
    robot.set_velocity(0.1, 0.2, duration=4.0, accel=0.3)  # a curve to the left
    robot.stop()


def sim_config(folder: Path, port: int, webapi: str = "") -> Path:
    """``folder``/sim.toml: the simulated robot with its router on ``port`` and its files in ``folder``;
    ``webapi``: more lines of its [webapi] table (default: a free port)."""
    cfg = folder / "sim.toml"
    cfg.write_text(f'extends = "sim"\nrun_dir = "{folder}/run"\n[webapi]\n{webapi or f"port = {free_port()}"}\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
    return cfg


def record(folder: Path, rrd: Path) -> None:
    port = free_port()
    cfg = sim_config(folder, port)
    config = config_mod.load(cfg)
    procs = [start("icefloe.router", cfg, log=folder / "router.log")]
    try:
        wait("the router", lambda: viewer.listening(port))
        viz_log = folder / "viz.log"
        procs.append(start("icefloe.services.viz", cfg, "--robot", config.name, "--save", str(rrd), log=viz_log))
        wait("viz", lambda: "showing robot" in viz_log.read_text(errors="replace"))
        procs += [start(f"icefloe.services.{s}", cfg, log=folder / f"{s}.log") for s in config.services]
        with Robot(config=config, timeout=60.0) as robot:
            _ = robot.pose, robot.landmarks  # each waits for its first message: odometry and the camera are up
            time.sleep(2.0)
            drive(robot)
        bad = raw_session(config)  # a bad command, as from a student's own program: hwbridge logs it
        bad.put(keys.key(config.name, keys.TWIST), b'{"v": "fast"}', encoding="application/json")
        time.sleep(3.0)
        bad.close()
    finally:
        stop(procs)


def screenshot(rrd: Path, out: Path) -> None:
    from rerun.experimental import ViewerClient

    stamps = [s for columns in read_rrd(rrd).values() for s in columns.get(TIMELINE, []) if s]
    cursor = (max(stamps) - 2_000_000_000) / 1e9  # 2 s before the end, seconds since the epoch
    port = free_port()
    # The viewer opens the recording itself at start (asking it to over gRPC times out on a busy machine).
    proc = subprocess.Popen([viewer.executable(), "--headless", "--port", str(port), "--hide-welcome-screen",
                             str(rrd)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait("the headless viewer", lambda: viewer.listening(port))
        client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
        for attempt in range(10):  # each call waits at most 15 s; loading and laying out may take longer
            try:
                time.sleep(3.0)
                client.set_time(TIMELINE, timestamp=cursor, play_state="paused")
                time.sleep(3.0)
                client.save_screenshot(str(out))
                break
            except TimeoutError:
                if attempt == 9:
                    raise
    finally:
        proc.terminate()
        try:
            proc.wait(30)  # a starved machine may take a while to tear the viewer down
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=OUT, help=f"where the PNG goes (default {OUT})")
    parser.add_argument("--keep", type=Path, help="also keep the recording (.rrd) here")
    parser.add_argument("--from-rrd", type=Path, help="take the screenshot of this recording instead of making one")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="icefloe-shot-") as tmp:
        folder = Path(tmp)
        rrd = args.from_rrd or args.keep or folder / "run.rrd"
        if not args.from_rrd:
            record(folder, rrd)
        screenshot(rrd.resolve(), args.out.resolve())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
