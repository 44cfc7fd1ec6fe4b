"""The `extloc` verbs: the lab's overhead camera (docs/extloc.md).

``icefloe extloc calibrate LAB_CONFIG`` finds the overhead camera's pose from the floor markers
of the world file (``[[floor_marker]]``), in a live frame of ``overhead.source`` or in an image
file, with the lens of ``overhead.calibration`` (``icefloe calibrate``'s intrinsics), writes it
where ``overhead.pose`` says (or ``--out``) and prints how good the fit is: the reprojection
error in pixels and the error on the floor in millimetres.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .. import config as config_mod
from ..errors import IcefloeError

if TYPE_CHECKING:
    import numpy as np

# OpenCV and the localizer are imported when the verb runs: `icefloe` itself starts without them.


def read_frame(config: config_mod.RobotConfig, image: str | None) -> np.ndarray:
    import cv2
    import numpy as np

    from ..services.extloc.sources import open_overhead
    from ..vision.sources import check_frame

    ov = config.overhead
    if image:
        data = np.fromfile(image, dtype=np.uint8) if Path(image).is_file() else np.zeros(0, np.uint8)
        frame = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
        if frame is None:
            raise IcefloeError(f"{image}: no such image, or not one OpenCV can read")
    else:  # one live frame (the simulated camera: the floor, no robots)
        source = open_overhead(ov, [])
        try:
            frame = source.read()[1]
        finally:
            source.close()
    try:
        return check_frame(frame, ov.width, ov.height)
    except IcefloeError as exc:
        raise IcefloeError(f"{image or ov.source}: {exc}") from None


def calibrate(args: argparse.Namespace) -> int:
    from ..services.extloc import locate
    from ..services.extloc.tracker import overhead_intrinsics
    from ..vision.overhead import save_pose
    from ..worldmap import load_world

    config = config_mod.load(args.config)
    ov = config.overhead
    out = args.out or ov.pose
    if not out:
        raise IcefloeError(f"{config.source}: overhead.pose is not set: say where to write the pose with --out")
    intrinsics = overhead_intrinsics(config)
    world = load_world(ov.world)
    frame = read_frame(config, args.image)
    found = locate.calibrate(intrinsics, world, locate.find_markers(locate.make_detector(ov.dictionary), frame))
    save_pose(Path(out).expanduser(), found.pose, intrinsics, found.rms_px, found.rms_floor_m)
    x, y, z = (f"{v:.3f}".replace("-0.000", "0.000") for v in found.pose.lens)  # no "-0.000 m"
    lens = "nominal, focal_px" if not ov.calibration else ov.calibration
    used = ", ".join(map(str, found.markers))
    print(f"floor markers used: {used} of {len(world.floor_markers)} in world {world.name}")
    print(f"camera lens at x {x} m, y {y} m, {z} m above the floor (lens: {lens})")
    print(f"reprojection error: {found.rms_px:.2f} px RMS")
    print(f"on the floor: {found.rms_floor_m * 1000:.1f} mm RMS, {found.worst_floor_m * 1000:.1f} mm worst")
    print(f"wrote {out}")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("extloc", help="the lab's overhead camera: find its pose from the floor markers",
                         description="The lab's external localizer (docs/extloc.md).")
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION", help="calibrate")
    c = sub.add_parser("calibrate", help="find the overhead camera's pose from the world's floor markers",
                       description=__doc__.split("\n\n")[1].replace("\n", " "))
    c.add_argument("config", metavar="LAB_CONFIG", help="the lab's config, with [overhead] (a name or a .toml path)")
    c.add_argument("--image", metavar="FILE", help="use this picture of the camera's instead of a live frame")
    c.add_argument("--out", metavar="FILE", help="write the pose here (default: overhead.pose of the config)")
    c.set_defaults(run=calibrate)
