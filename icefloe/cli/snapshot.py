"""The `snapshot` verb: save one full-resolution frame of the robot's camera (``camera/snapshot``)."""

from __future__ import annotations

import argparse
import asyncio
import time
from pathlib import Path

import cv2
import numpy as np

from ..config import RobotConfig
from ..errors import BadPayload, IcefloeError, NotReachable
from ..runtime import Node, run_async
from ..schemas import keys
from ..schemas import messages as m
from .common import add_bus_arguments, bus_config, cli_node

JPEG_SUFFIXES = (".jpg", ".jpeg")


def save(image: m.Image, path: Path) -> None:
    """Write a `camera/snapshot` answer: its JPEG bytes as they are, or decoded into another
    format OpenCV writes (``.png``, ``.bmp`` ...), chosen by the suffix."""
    if path.suffix.lower() in JPEG_SUFFIXES:
        path.write_bytes(image.data)
        return
    frame = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
    if frame is None:
        raise IcefloeError("camera/snapshot: the answer is not a decodable JPEG")
    try:
        written = cv2.imwrite(str(path), frame)
    except cv2.error:
        written = False
    if not written:
        raise IcefloeError(f"{path}: cannot write a {path.suffix or 'suffix-less'} image "
                           f"(use .jpg, or .png, .bmp, .tiff)")


async def ask(node: Node, robot: str, timeout: float) -> m.Image:
    """The camera's answer, asked again until ``timeout`` while the camera service is not up yet or
    has no frame yet (it has just started)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return await node.query(keys.SNAPSHOT, m.Stop(), timeout=max(0.5, deadline - time.monotonic()),
                                    robot=robot)
        except (NotReachable, BadPayload) as exc:
            if time.monotonic() > deadline:
                raise IcefloeError(f"{exc} (after {timeout:.0f} s)") from None
        await asyncio.sleep(0.3)


async def snapshot(args: argparse.Namespace, config: RobotConfig) -> int:
    path = Path(args.file)
    if not path.parent.is_dir():
        raise IcefloeError(f"{path}: no folder {path.parent} to save it in")
    async with cli_node(config) as node:
        image = await ask(node, args.robot or config.name, args.timeout)
    save(image, path)
    age = (time.time_ns() - image.stamp) / 1e9
    print(f"{path}: {image.width}x{image.height}, {path.stat().st_size} bytes, taken {age:.2f} s ago")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("snapshot", help="save one full-resolution frame of the robot's camera",
                         description="Ask the camera service for its latest frame at full resolution "
                                     "(the camera/snapshot query) and save it: a .jpg as the camera "
                                     "sent it, another suffix (.png ...) converted.")
    add_bus_arguments(p)
    p.add_argument("file", metavar="FILE", help="where to save it, e.g. frame.jpg")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait this long for the camera")
    p.set_defaults(run=lambda args: run_async(snapshot(args, bus_config(args))))
