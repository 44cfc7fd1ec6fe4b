"""Regenerate the robot page's screenshot (docs/webapi-page.png): the page at ``/`` of the web API
in Debian's Chromium (Playwright, as tests/test_webapi_page.py drives it), on the real simulated
stack while a program drives the robot past the lab's markers.

    .venv/bin/python tools/page_screenshot.py                      # about half a minute
    .venv/bin/python tools/page_screenshot.py --out /tmp/page.png
    PAGE_SHOT_DIR=/tmp/shot .venv/bin/python tools/page_screenshot.py   # keep the services' logs there
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import threading
from pathlib import Path

from viz_screenshot import free_port, sim_config, start, stop, wait

from icefloe import config as config_mod
from icefloe.client import Robot
from icefloe.services.viz import viewer

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "webapi-page.png"
sys.path.insert(0, str(ROOT / "tests"))
from browser import chromium  # noqa: E402  (the browser tests' Chromium, its options and profile)


def drive(robot: Robot, done: threading.Event) -> None:
    """A slow curve to the left, so the pose moves and the camera sees markers; stops at the end."""
    robot.print_oled("icefloe\nthe robot's page")
    robot.set_velocity(0.1, 0.14, duration=8.0, accel=0.3)
    done.set()


async def shoot(base: str, out: Path, profile: Path, robot: Robot) -> None:
    done = threading.Event()
    async with chromium(profile) as context:
        page = await context.new_page()  # type: ignore[attr-defined]
        await page.goto(base + "/")
        await page.wait_for_selector("#link.up", timeout=60_000)
        driver = threading.Thread(target=drive, args=(robot, done), daemon=True)
        driver.start()
        await asyncio.sleep(6.0)  # moving: the pose, the camera's markers, the log fill in
        await page.screenshot(path=str(out), full_page=True)
        await asyncio.to_thread(driver.join, 30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=OUT, help=f"where the PNG goes (default {OUT})")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="icefloe-page-") as tmp:
        folder = Path(os.environ.get("PAGE_SHOT_DIR", tmp))
        port, http = free_port(), free_port()
        cfg = sim_config(folder, port, webapi=f'host = "127.0.0.1"\nport = {http}')
        config = config_mod.load(cfg)
        procs = [start("icefloe.router", cfg, log=folder / "router.log")]
        try:
            wait("the router", lambda: viewer.listening(port))
            procs += [start(f"icefloe.services.{s}", cfg, log=folder / f"{s}.log") for s in config.services]
            with Robot(config=config, timeout=60.0) as robot:
                _ = robot.pose, robot.landmarks  # each waits for its first message: odometry and the camera
                asyncio.run(shoot(f"http://127.0.0.1:{http}", args.out.resolve(), folder / "profile", robot))
                robot.stop()
        finally:
            stop(procs)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
