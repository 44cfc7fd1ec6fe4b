"""Collect labelled images for the RVSS workshop's steering network: drive by keys, save what the camera saw.

    python examples/rvss_collect.py --client ~/RVSS_Need4Speed --folder data/train
    python examples/rvss_collect.py --client pibot_client.py --ip 192.168.50.5 --folder data/train --im_num 500

As the workshop's ``scripts/collect.py`` does, through the same unchanged client (examples/rvss_client.py):
the arrow keys steer (left/right: the angle -/+ 0.1, clipped to +-0.5; up or down: straight again),
space stops the robot and ends. Ten times a second it takes ``getImage()``, drives
``setVelocity(int(15 + 15 * angle), int(15 - 15 * angle))`` and writes the image as
``<6-digit number><angle with 2 decimals>.jpg`` (``000042-0.20.jpg``): the workshop's
``steerDS.py`` reads the label back from the name (everything after the 6th character). The
keys come from this terminal (collect.py listens with pynput, which needs a desktop session).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import sys
import termios
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
from rvss_client import ClientNotFound, load_client

KEYS = {b"\x1b[A": "up", b"\x1b[B": "down", b"\x1b[C": "right", b"\x1b[D": "left", b" ": "space", b"q": "space"}
"""What a terminal sends for each key collect.py listens to (``q`` also ends, as in collect_wsl.py)."""
BASE_SPEED = 15
"""collect.py's ``Kd``: both wheels' demand when driving straight (about 8 cm/s)."""
TURN_GAIN = 15
"""collect.py's ``Ka``: the wheels' difference per unit of angle."""
PERIOD_S = 0.1
"""collect.py's loop: ``time.sleep(0.1)`` after each image."""


def image_name(number: int, angle: float) -> str:
    """collect.py's file name: ``str(im_number).zfill(6) + '%.2f' % angle + ".jpg"``."""
    return str(number).zfill(6) + "%.2f" % angle + ".jpg"  # noqa: UP031 - collect.py's own expression


def steer(angle: float, key: str) -> float:
    """The angle after ``key``, as collect.py's ``on_press`` changes it."""
    if key in ("up", "down"):
        return 0
    if key == "right":
        return angle + 0.1
    if key == "left":
        return angle - 0.1
    return angle


def wheel_speeds(angle: float) -> tuple[int, int]:
    """collect.py's wheel demands for an angle (clipped to +-0.5 first, as it does)."""
    return int(BASE_SPEED + TURN_GAIN * angle), int(BASE_SPEED - TURN_GAIN * angle)


@contextlib.contextmanager
def keys_from_terminal() -> Iterator[Callable[[], list[str]]]:
    """A function that returns the keys pressed since it was last called, the terminal in cbreak mode."""
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd)
    pending = b""

    def pressed() -> list[str]:
        nonlocal pending
        while select.select([fd], [], [], 0)[0]:
            chunk = os.read(fd, 64)
            if not chunk:
                break
            pending += chunk
        found = []
        while pending:
            for sequence, name in KEYS.items():
                if pending.startswith(sequence):
                    found.append(name)
                    pending = pending[len(sequence):]
                    break
            else:
                if pending == b"\x1b" or pending == b"\x1b[":  # the rest of an arrow is on its way
                    break
                pending = pending[1:]  # a key collect.py does not listen to
        return found

    try:
        yield pressed
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--client", required=True,
                        help="the workshop checkout (RVSS_Need4Speed), a PenguinPi-robot checkout, or pibot_client.py")
    parser.add_argument("--ip", default="localhost", help="the robot's address (collect.py's --ip)")
    parser.add_argument("--port", type=int, default=8080, help="the robot's web API port")
    parser.add_argument("--im_num", type=int, default=0, help="number of the first image (collect.py's --im_num)")
    parser.add_argument("--folder", default="data/train", help="where the images go (made if missing)")
    parser.add_argument("--countdown", type=int, default=3, help="seconds of 'Get ready' before it drives")
    args = parser.parse_args()
    try:
        pibot = load_client(args.client)
    except ClientNotFound as error:
        sys.exit(f"rvss_collect: {error}")
    if not sys.stdin.isatty():
        sys.exit("rvss_collect: the keys come from the terminal: run it in one (stdin is not a terminal)")
    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)

    bot = pibot.PiBot(ip=args.ip, port=args.port)
    bot.setVelocity(0, 0)
    print("Get ready...", flush=True)
    for count in range(args.countdown, 0, -1):
        time.sleep(1)
        print(count, flush=True)
    print("GO! arrows steer, space stops", flush=True)

    angle: float = 0
    number = args.im_num
    try:
        with keys_from_terminal() as pressed:
            while True:
                keys = pressed()
                if "space" in keys:
                    break
                for key in keys:
                    angle = steer(angle, key)
                    print({"up": "straight", "right": "right", "left": "left"}.get(key, key), flush=True)
                image = bot.getImage()
                angle = float(np.clip(angle, -0.5, 0.5))
                if image is None:  # the client's reader lost the stream: no picture, no driving
                    bot.setVelocity(0, 0)
                    time.sleep(PERIOD_S)
                    continue
                left, right = wheel_speeds(angle)
                bot.setVelocity(left, right)
                cv2.imwrite(str(folder / image_name(number, angle)), image)
                number += 1
                time.sleep(PERIOD_S)
    except KeyboardInterrupt:
        pass
    finally:
        bot.setVelocity(0, 0)
    print(f"stop: {number - args.im_num} images in {folder}, the next is --im_num {number}", flush=True)
    # pibot_client's camera thread never ends (a daemon blocked in OpenCV's read): a normal
    # interpreter exit tears it down mid-read and the process aborts ("FATAL: exception not rethrown").
    os._exit(0)


if __name__ == "__main__":
    main()
