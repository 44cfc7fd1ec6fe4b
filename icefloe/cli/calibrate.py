"""The `calibrate` verb: measure the robot camera's intrinsics from views of a printed board.

The views are full-resolution snapshots (``camera/snapshot``); the board is found and the
intrinsics computed by OpenCV (``icefloe/vision/calibration.py``); the result is written as
the calibration file the camera service reads (``[camera] calibration``), and the robot
config is pointed at it. A ChArUco board printed with the robot's own marker dictionary also
measures how far inside its squares the marker detector puts their corners; with ``--drive``,
a slow turn back and forth in front of the board measures the capture latency. Both go into the
same file; whatever was not measured this time is kept from the calibration the robot had.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import re
import time
from pathlib import Path

import cv2
import numpy as np

from .. import config as config_mod
from .. import paths
from ..client import AsyncRobot
from ..config import RobotConfig
from ..errors import ConfigError, IcefloeError
from ..runtime import run_async
from ..schemas import keys
from ..schemas import messages as m
from ..vision import calibration as cal
from ..vision.aruco import aruco_dictionary
from ..vision.geometry import CameraCalibration, Intrinsics, calibration_extras, save_calibration
from .common import add_bus_arguments, bus_config

DESCRIPTION = """\
Calibrate the robot's camera: capture views of a printed chessboard (or ChArUco board),
compute the camera matrix and lens distortion with OpenCV, write them to a calibration
file, and set [camera] calibration to it in the robot config. The camera service reads
it when it starts.

Interactive (the default): hold the board in front of the camera and press Enter for
each view; move the board (or the robot) between views: near and far, tilted every way,
in every part of the picture, its corners most of all. u drops the last view, q (or
Ctrl-D) computes. --auto N captures N views without questions, each time the board is
seen somewhere new; with --drive the robot turns and backs up by itself between them
(stand the board about 0.5 m ahead of it, leaning back a little), then turns slowly back
and forth in front of it to measure the camera's latency.

A ChArUco board printed with the robot's marker dictionary (--dictionary DICT_4X4_50) also
measures the camera service's marker detector: how far inside each black square it puts
the corners, which makes every range long until the camera service moves them out again.
"""
MIN_VIEWS = 10
"""Interactive: views before q computes (fewer if the user insists twice)."""
NEW_VIEW_PX = 25.0
"""--auto: a view is new when its corners are on average this far from every earlier view's, px."""
AUTO_PERIOD_S = 0.5
"""--auto without --drive: time between snapshots, s."""
GOOD_RMS_PX, POOR_RMS_PX = 0.5, 1.0
"""What an RMS reprojection error means: below 0.5 px good, above 1 px a view is probably bad."""
SWAY_RATE, SWAY_S, SWAYS = 0.5, 0.8, 3
"""--drive: the latency is measured turning at this many rad/s for this long one way, then the
other, this many times (about 11° either side of where the board is in the middle of the picture;
slower, the PenguinPi's wheels would hardly turn)."""
SCAN_ROWS_M = (0.0, -0.1, -0.2, -0.3, -0.4)
"""--drive: the robot looks at the board from its start and from these many metres back ..."""
SCAN_STEP_DEG, SCAN_MAX_DEG = 6.0, 30.0
"""... turning away from its start heading in steps of this many degrees, to each side until it
loses the board (or this far): the board crosses the picture, whatever its size and distance."""
PARTS = (("top-left", "top", "top-right"), ("left", "centre", "right"),
         ("bottom-left", "bottom", "bottom-right"))


def board_of(args: argparse.Namespace) -> cal.Board:
    match = re.fullmatch(r"(\d+)x(\d+)", args.squares)
    if not match:
        raise IcefloeError(f"--squares: expected COLUMNSxROWS such as 10x7, got {args.squares!r}")
    marker = args.marker or (0.75 * args.square if args.board == "charuco" else 0.0)
    try:
        return cal.Board(int(match[1]), int(match[2]), args.square, args.board, marker, args.dictionary,
                         args.first_id)
    except ValueError as exc:
        raise IcefloeError(f"board: {exc}") from None


def coverage(views: list[cal.View], width: int, height: int) -> str:
    counts = cal.region_counts(views, width, height)
    missing = [PARTS[r][c] for r in range(3) for c in range(3) if counts[r, c] == 0]
    return "every part of the picture" if not missing else \
        f"{9 - len(missing)} of 9 parts of the picture (none yet: {', '.join(missing)})"


class Capture:
    """Snapshots from the robot, the board found in them, the views kept."""

    def __init__(self, robot: AsyncRobot, finder: cal.Finder, save_dir: Path | None) -> None:
        self.robot, self.finder, self.save_dir = robot, finder, save_dir
        self.views: list[cal.View] = []
        self.size: tuple[int, int] | None = None

    async def snapshot(self, newer_than: int = 0) -> tuple[m.Image, np.ndarray]:
        """A full-resolution frame (taken after ``newer_than``, ns since the epoch, if given)."""
        for _ in range(50):
            image: m.Image = await self.robot.node.query(keys.SNAPSHOT, m.Stop(), timeout=self.robot.timeout)
            if image.stamp > newer_than:
                break
            await asyncio.sleep(0.05)
        frame = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
        if frame is None:
            raise IcefloeError("camera/snapshot: the answer is not a decodable JPEG")
        if self.size is None:
            self.size = (frame.shape[1], frame.shape[0])
        elif self.size != (frame.shape[1], frame.shape[0]):
            raise IcefloeError(f"camera/snapshot: the frame size changed from {self.size} to "
                               f"{frame.shape[1]}x{frame.shape[0]} (camera restarted?): start again")
        return image, frame

    async def look(self, newer_than: int = 0) -> tuple[cal.View | None, m.Image]:
        image, frame = await self.snapshot(newer_than)
        return await asyncio.to_thread(self.finder.find, frame), image

    def keep(self, view: cal.View, image: m.Image) -> None:
        self.views.append(view)
        if self.save_dir is not None:
            (self.save_dir / f"view-{len(self.views):02d}.jpg").write_bytes(image.data)
        assert self.size is not None
        print(f"view {len(self.views)}: board found ({view.count} corners); the views so far cover "
              f"{coverage(self.views, *self.size)}", flush=True)

    def is_new(self, view: cal.View) -> bool:
        return all(cal.view_distance(view, kept) > NEW_VIEW_PX for kept in self.views)


async def interactive(capture: Capture, board: cal.Board) -> None:
    print(f"Hold {board.describe()} in front of the camera.\n"
          f"Enter: capture a view   u: drop the last one   q (or Ctrl-D): compute (after {MIN_VIEWS} views)",
          flush=True)
    insisted = False
    while True:
        try:
            answer = (await asyncio.to_thread(input, f"[{len(capture.views)} views] > ")).strip().lower()
        except EOFError:
            answer = "q"
        if answer == "q":
            if len(capture.views) >= MIN_VIEWS or (insisted and len(capture.views) >= 3):
                return
            if len(capture.views) < 3:
                raise IcefloeError(f"calibrate: {len(capture.views)} views are too few (3 at least, "
                                   f"{MIN_VIEWS} or more is good); nothing written")
            print(f"{len(capture.views)} views: {MIN_VIEWS} or more make a good calibration. q again computes "
                  f"anyway.", flush=True)
            insisted = True
        elif answer == "u":
            if capture.views:
                capture.views.pop()
                print(f"dropped view {len(capture.views) + 1}", flush=True)
        elif answer == "":
            view, image = await capture.look()
            if view is None:
                print("no board found: the whole board must be in the picture (a ChArUco board: "
                      "6 corners at least), lit evenly, not blurred", flush=True)
            elif not capture.is_new(view):
                print("the board is where it was in an earlier view: move it (or the robot) first", flush=True)
            else:
                capture.keep(view, image)
        else:
            print("Enter, u or q", flush=True)


async def automatic(capture: Capture, wanted: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while len(capture.views) < wanted:
        if time.monotonic() > deadline:
            raise IcefloeError(f"calibrate: {len(capture.views)} of {wanted} views in {timeout:.0f} s: is the "
                               f"board in the picture, and does it move between views? Nothing written")
        view, image = await capture.look()
        if view is not None and capture.is_new(view):
            capture.keep(view, image)
        else:
            await asyncio.sleep(AUTO_PERIOD_S)


class Scan:
    """--drive: the robot looks at the board from a few places (`views`), and can come back to its start."""

    def __init__(self, capture: Capture) -> None:
        self.capture, self.robot = capture, capture.robot
        self.backed = 0.0
        self.start: m.Pose | None = None

    async def face(self, heading_deg: float) -> None:
        here, start = self.robot.pose, self.start
        assert here is not None and start is not None
        await self.robot.turn(math.remainder(start.theta + math.radians(heading_deg) - here.theta, math.tau))

    async def back_to_start(self) -> None:
        print("driving back to the start", flush=True)
        await self.face(0)
        if self.backed:
            await self.robot.forward(-self.backed)

    async def views(self, wanted: int) -> None:
        """Views until ``wanted`` are kept. A stop, a blocked wheel or Ctrl-C ends the scan where the
        robot is (no driving back then); not enough views drive back and raise."""
        capture = self.capture
        await self.robot.ready(keys.ODOM_POSE.name)
        self.start = self.robot.pose
        for row in SCAN_ROWS_M:
            if row != self.backed:
                await self.face(0)
                await self.robot.forward(row - self.backed)
                self.backed = row
            for side in (1, -1):
                heading = 0.0 if side == 1 else -SCAN_STEP_DEG
                while abs(heading) <= SCAN_MAX_DEG:
                    await self.face(heading)
                    view, image = await capture.look(newer_than=time.time_ns())
                    if view is not None and capture.is_new(view):
                        capture.keep(view, image)
                    if len(capture.views) >= wanted:
                        return
                    if view is None and heading != 0:
                        break  # the board has left the picture on this side
                    heading += side * SCAN_STEP_DEG
        await self.back_to_start()
        raise IcefloeError(f"calibrate --drive: {len(capture.views)} of {wanted} views after the whole scan: "
                           f"stand the board about 0.5 m ahead of the robot, facing it; nothing written")

    async def latency(self, intrinsics: Intrinsics) -> cal.LatencyFit | None:
        """Turn slowly back and forth facing the board; fit the lag of the board's yaw in the frames
        behind odometry's heading (`cal.fit_latency`), plus what the camera already takes off."""
        robot, node = self.robot, self.robot.node
        await self.face(0)
        info: m.CameraInfo = await node.query(keys.CAMERA_INFO, m.Stop(), timeout=robot.timeout)
        headings: list[tuple[int, float]] = []
        frames: list[tuple[int, float]] = []
        unwrapped = [0.0, 0.0]  # last raw heading, unwrapped heading

        async def follow() -> None:
            async for pose in node.subscribe(keys.ODOM_POSE, latest=False, maxsize=256):
                if headings:
                    unwrapped[1] += math.remainder(pose.theta - unwrapped[0], math.tau)
                else:
                    unwrapped[1] = pose.theta
                unwrapped[0] = pose.theta
                headings.append((pose.stamp, unwrapped[1]))

        async def watch() -> None:
            while True:
                view, image = await self.capture.look()
                fresh = not frames or image.stamp != frames[-1][0]
                if fresh and view is not None and (yaw := cal.board_yaw(view, intrinsics)) is not None:
                    frames.append((image.stamp, yaw))

        print("turning slowly back and forth in front of the board: the camera's latency", flush=True)
        tasks = [asyncio.create_task(follow()), asyncio.create_task(watch())]
        try:
            await asyncio.sleep(0.3)
            for i in range(2 * SWAYS + 1):  # half a sway first, so it ends where it started
                rate = SWAY_RATE if i % 2 == 0 else -SWAY_RATE
                await robot.drive(0.0, rate, SWAY_S / 2 if i in (0, 2 * SWAYS) else SWAY_S)
            await robot.stop()
            await asyncio.sleep(0.3)
        finally:
            for task in tasks:
                task.cancel()
        fit = cal.fit_latency(frames, headings)
        if fit is None:
            return None
        return cal.LatencyFit(fit.latency_s + info.capture_latency_s, fit.frames, fit.residual, fit.gain)


# ---------------------------------------------------------------------- writing the result


def calibration_paths(config: RobotConfig, output: str | None) -> tuple[Path, Path]:
    """(the robot config file to point at the calibration, the calibration file).

    A shipped config is not edited: your own config of the same name extends it
    (``~/.config/icefloe/robots/<name>.toml``), and that one is."""
    source = Path(config.source) if config.source else config_mod.find(None)
    shipped = paths.packaged("robots").resolve()
    if source.resolve().parent == shipped:
        source = paths.user_dir() / "robots" / source.name
        if not source.exists():
            source.parent.mkdir(parents=True, exist_ok=True)
            source.write_text(f'# Your own settings for the robot "{source.stem}", over the shipped config.\n'
                              f'extends = "{source.stem}"\n')
    calibration = Path(output) if output else source.with_name(f"{source.stem}.camera.yaml")
    return source, calibration.expanduser().resolve()


def point_config_at(config_file: Path, calibration: Path) -> None:
    """Set ``[camera] calibration = "<calibration>"`` in ``config_file``, keeping the rest of its text."""
    text = config_file.read_text()
    line = f"calibration = {json.dumps(str(calibration))}"
    lines = text.splitlines()
    header = next((i for i, ln in enumerate(lines) if re.match(r"\s*\[camera\]\s*(#.*)?$", ln)), None)
    if header is None:
        new = text.rstrip("\n") + f"\n\n[camera]\n{line}\n"
    else:
        end = next((i for i in range(header + 1, len(lines)) if re.match(r"\s*\[", lines[i])), len(lines))
        key = next((i for i in range(header + 1, end) if re.match(r"\s*calibration\s*=", lines[i])), None)
        if key is None:
            lines.insert(header + 1, line)
        else:
            lines[key] = line
        new = "\n".join(lines) + "\n"
    config_file.write_text(new)
    try:
        if config_mod.load(config_file).camera.calibration != str(calibration):
            raise ConfigError(f"{config_file}: camera.calibration did not take (a dotted key or an inline "
                              f"[camera] table?); set it by hand to {calibration}")
    except ConfigError:
        config_file.write_text(text)  # as it was
        raise


def sizes_note(intrinsics: Intrinsics, config: RobotConfig) -> str:
    """What a calibration file holds for which frame size, and what HTTP clients get of it."""
    cam = config.camera
    small = intrinsics.scaled(cam.image_width, cam.image_height)
    k = small.camera_matrix
    return (f"for {intrinsics.width}x{intrinsics.height} frames (the camera's capture size, camera/snapshot); "
            f"the {small.width}x{small.height} JPEGs of camera/image and the web API's /camera/get get it scaled: "
            f"fx {k[0, 0]:.1f} px  fy {k[1, 1]:.1f} px  cx {k[0, 2]:.1f} px  cy {k[1, 2]:.1f} px, same distortion "
            f"(GET /camera/info, or the camera/info query, once the camera service has restarted)")


def report(result: cal.Calibration, views: list[cal.View]) -> None:
    k, d = result.intrinsics.camera_matrix, result.intrinsics.dist_coeffs
    quality = "good" if result.rms < GOOD_RMS_PX else "usable" if result.rms < POOR_RMS_PX else "poor"
    print(f"{len(views)} views, {sum(v.count for v in views)} corners: RMS reprojection error "
          f"{result.rms:.3f} px, {quality} (under {GOOD_RMS_PX} px is good; over {POOR_RMS_PX} px, "
          f"some views are bad)")
    print(f"  fx {k[0, 0]:.1f} px  fy {k[1, 1]:.1f} px  cx {k[0, 2]:.1f} px  cy {k[1, 2]:.1f} px")
    print("  distortion k1 {:.4f}  k2 {:.4f}  p1 {:.4f}  p2 {:.4f}  k3 {:.4f}".format(*d[:5]))
    worst = int(np.argmax(result.view_errors))
    if result.view_errors[worst] > 2 * max(result.rms, 0.1):
        print(f"  view {worst + 1} fits worst ({result.view_errors[worst]:.2f} px): blurred, or the board bent?")


def measured_extras(args: argparse.Namespace, config: RobotConfig, board: cal.Board, views: list[cal.View],
                    result: cal.Calibration, latency: cal.LatencyFit | None) -> CameraCalibration:
    """The marker inset and the capture latency to write: measured now, else the robot's calibration's."""
    try:
        before = calibration_extras(config.camera)
    except ConfigError:
        before = CameraCalibration()
    inset = before.inset
    bits = cv2.aruco.getPredefinedDictionary(aruco_dictionary(config.camera.dictionary)).markerSize
    if board.kind != "charuco":
        print("  marker corners: not measured (a chessboard has no markers; a ChArUco board of the robot's "
              f"dictionary, {config.camera.dictionary}, measures them)")
    elif cv2.aruco.getPredefinedDictionary(aruco_dictionary(board.dictionary)).markerSize != bits:
        print(f"  marker corners: not measured (the board's markers, {board.dictionary}, are not like the robot's, "
              f"{config.camera.dictionary}: print the board with those)")
    elif (fit := cal.measure_inset(views, result)) is None:
        print(f"  marker corners: not measured (fewer than {cal.MIN_INSET_SIGHTINGS} of the board's markers found)")
    else:
        inset = fit.inset
        print(f"  marker corners: {inset.at(25):.3f} px inside the square at 25 px, {inset.at(60):.3f} px at 60 px "
              f"(ranges {200 * inset.at(25) / 25:.1f} % and {200 * inset.at(60) / 60:.1f} % long, now undone; "
              f"{fit.markers} markers of {fit.sides[0]:.0f}-{fit.sides[1]:.0f} px, {fit.residual:.3f} px about "
              "the fit)")
    latency_s = before.latency_s
    if latency is not None:
        if abs(abs(latency.gain) - 1.0) > 0.25:
            print(f"  capture latency: not measured (the board's yaw turned {abs(latency.gain):.2f} times as much as "
                  f"odometry's heading, not once: did the board or the robot slip?)")
        else:
            latency_s = max(0.0, latency.latency_s)
            print(f"  capture latency: {latency_s * 1000:.0f} ms from exposure to arrival ({latency.frames} frames, "
                  f"{math.degrees(latency.residual):.2f}° about the fit)")
    elif args.drive:
        print("  capture latency: not measured (too few frames of the board while turning)")
    return CameraCalibration(inset, latency_s)


async def run(args: argparse.Namespace, config: RobotConfig) -> int:
    board = board_of(args)
    if args.auto is not None and args.auto < 3:
        raise IcefloeError(f"--auto: at least 3 views, got {args.auto}")
    if args.drive and args.auto is None:
        raise IcefloeError("--drive: only with --auto N (the robot moves between automatic captures)")
    robot_name = args.robot or config.name
    foreign = robot_name != config.name  # e.g. --credentials of penguin1 with the default sim config
    if foreign and not args.output and not args.dry_run:
        raise IcefloeError(f"calibrate: the config {config.source or 'sim'} is robot {config.name!r}, not "
                           f"{robot_name!r}: name its config (--config), or --output FILE to only write the file")
    save_dir = Path(args.save_views) if args.save_views else None
    if save_dir is not None:
        save_dir.mkdir(parents=True, exist_ok=True)
    async with AsyncRobot(args.robot, config=config, service="calibrate", timeout=args.timeout) as robot:
        capture = Capture(robot, cal.Finder(board), save_dir)
        await capture.snapshot()  # the camera answers, and its frame size
        assert capture.size is not None
        print(f"Calibrating the camera of robot {robot.name!r} ({capture.size[0]}x{capture.size[1]}) with "
              f"{board.describe()}.", flush=True)
        scan = Scan(capture) if args.drive else None
        if args.auto is None:
            await interactive(capture, board)
        elif scan is not None:
            await scan.views(args.auto)
        else:
            await automatic(capture, args.auto, args.auto_timeout)
        width, height = capture.size
        if (width, height) != (config.camera.width, config.camera.height) and not foreign:
            if scan is not None:
                await scan.back_to_start()
            raise IcefloeError(f"the camera sends {width}x{height} frames but {config.source} says "
                               f"{config.camera.width}x{config.camera.height} ([camera] width, height): the camera "
                               f"service would refuse this calibration; nothing written")
        if args.keep_intrinsics:
            result = await asyncio.to_thread(cal.with_intrinsics, capture.views, Intrinsics.from_config(config.camera))
        else:
            result = await asyncio.to_thread(cal.calibrate, capture.views, width, height)
        latency = None
        if scan is not None:
            latency = await scan.latency(result.intrinsics)
            await scan.back_to_start()
    report(result, capture.views)
    if args.keep_intrinsics:
        print(f"  (the intrinsics the camera had, {config.camera.calibration or 'nominal'}: kept)")
    extras = measured_extras(args, config, board, capture.views, result, latency)
    if args.dry_run:
        print("--dry-run: nothing written")
        return 0
    intrinsics = Intrinsics(result.intrinsics.camera_matrix, result.intrinsics.dist_coeffs, width, height)
    if foreign:
        calibration_file = Path(args.output).expanduser().resolve()
        save_calibration(calibration_file, intrinsics, result.rms, extras)
        print(f"wrote {calibration_file} {sizes_note(intrinsics, config)}")
        print(f"On robot {robot_name!r}, set [camera] calibration to it in its config, "
              f"then restart its camera service.")
        return 0
    config_file, calibration_file = calibration_paths(config, args.output)
    calibration_file.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(calibration_file, intrinsics, result.rms, extras)
    point_config_at(config_file, calibration_file)
    print(f"wrote {calibration_file} {sizes_note(intrinsics, config)}")
    print(f"set [camera] calibration to it in {config_file}\n"
          f"The camera service reads it when it starts: restart it (icefloe up: Ctrl-C and up again; "
          f"a robot: sudo systemctl restart icefloe@camera).")
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("calibrate", help="calibrate the robot's camera from views of a chessboard or ChArUco board",
                         description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_bus_arguments(p)
    p.add_argument("--board", choices=("chessboard", "charuco"), default="chessboard",
                   help="the printed board (default chessboard)")
    p.add_argument("--squares", default="10x7", metavar="CxR",
                   help="squares across and down (default 10x7: a chessboard of 9x6 inner corners)")
    p.add_argument("--square", type=float, default=0.025, metavar="M", help="side of a square, m (default 0.025)")
    p.add_argument("--marker", type=float, default=0.0, metavar="M",
                   help="ChArUco: side of a marker, m (default 3/4 of a square)")
    p.add_argument("--dictionary", default="DICT_5X5_100",
                   help="ChArUco: the markers' dictionary (default DICT_5X5_100; the robot's, e.g. DICT_4X4_50, "
                        "also measures its marker detector)")
    p.add_argument("--first-id", type=int, default=0, metavar="N", help="ChArUco: the id of the board's first marker")
    p.add_argument("--keep-intrinsics", action="store_true",
                   help="keep the camera matrix and distortion the camera has (its calibration, or nominal): "
                        "measure only the marker detector and the latency")
    p.add_argument("--auto", type=int, metavar="N", help="no questions: capture N views, each when the board is "
                                                         "seen somewhere new")
    p.add_argument("--drive", action="store_true",
                   help="with --auto: the robot turns and backs up by itself between views, measures the camera's "
                        "latency turning back and forth, then comes back")
    p.add_argument("--auto-timeout", type=float, default=120.0, metavar="S",
                   help="--auto without --drive: give up after this long (default 120 s)")
    p.add_argument("--output", metavar="FILE",
                   help="the calibration file to write (default: <robot config>.camera.yaml beside the config)")
    p.add_argument("--save-views", metavar="DIR", help="also save each view kept as a JPEG in DIR")
    p.add_argument("--dry-run", action="store_true", help="compute and print, write nothing")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S", help="wait this long for the robot's answers")
    p.set_defaults(run=lambda args: run_async(run(args, bus_config(args))))
