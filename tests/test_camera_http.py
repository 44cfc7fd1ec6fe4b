"""``/camera/get`` as course clients read it, against the simulated robot.

Real processes (router, simulator, camera, two webapi: one streaming, one with
``[webapi] camera_get = "frame"``), started once for the module. The clients are written from
the behaviour the courses rely on: a raw socket that cuts JPEGs at the ``--frame`` boundary
(HTTP/1.1 and 1.0), and a one-shot client (requests, 0.1 s timeout). Every JPEG is decoded
with OpenCV. Then what a hostile student tries: clients that never read, one that leaves in
the middle of a part, bad query strings. About 3 min on a 2-core machine at load average 25.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import requests
from conftest import SIM_CONFIG, Proc, Robot, free_port

from icefloe import config as config_mod
from icefloe.cli.calibrate import sizes_note
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.webapi.camera import MAX_WATCHERS, STALL_S
from icefloe.vision.geometry import Intrinsics, save_calibration

HEAD = b"--frame\r\nContent-Type: image/jpeg\r\n\r\n"
CALIBRATED = Intrinsics(np.array([[505.6, 0.0, 322.4], [0.0, 504.9, 241.7], [0.0, 0.0, 1.0]]),
                        np.array([0.08, -0.2, 0.001, -0.002, 0.1]), 640, 480)
"""A calibration at the capture size, as `icefloe calibrate` writes one."""


class Stack:
    def __init__(self, robot: Robot, stream_port: int, frame_port: int, webapi: Proc, oneshot: Proc) -> None:
        self.robot, self.stream_port, self.frame_port = robot, stream_port, frame_port
        self.webapi, self.oneshot = webapi, oneshot

    def url(self, path: str, port: int | None = None) -> str:
        return f"http://127.0.0.1:{port or self.stream_port}{path}"


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("camera_http")
    calibration = tmp / "camera.yaml"
    save_calibration(calibration, CALIBRATED, 0.1)
    stream_port = frame_port = free_port()
    while frame_port == stream_port:  # a port just given back may come again
        frame_port = free_port()
    # The bus's thumbnails at 0.5 Hz: a stream at the capture rate cannot be them.
    robot = Robot(tmp, f'[camera]\nimage_rate_hz = 0.5\ncalibration = "{calibration}"\n'
                       f'[webapi]\nhost = "127.0.0.1"\nport = {stream_port}\n')
    try:
        robot.start("sim")
        robot.start("camera")
        webapi = robot.start("webapi")
        oneshot_config = tmp / "oneshot.toml"
        oneshot_config.write_text(f'extends = "{robot.config_path}"\n'
                                  f'[webapi]\nport = {frame_port}\ncamera_get = "frame"\n')
        oneshot = Proc("webapi-oneshot", [*webapi.popen.args[:3], "--config", str(oneshot_config)],
                       tmp / "webapi-oneshot.log", robot.env)
        robot.procs.append(oneshot)
        s = Stack(robot, stream_port, frame_port, webapi, oneshot)
        deadline = time.monotonic() + 90
        for port in (stream_port, frame_port):
            while True:
                assert webapi.alive() and oneshot.alive(), webapi.output + oneshot.output
                with contextlib.suppress(requests.RequestException):
                    if requests.get(s.url("/camera/frame", port), timeout=5).status_code == 200:
                        break
                assert time.monotonic() < deadline, "no frame from the simulated camera:\n" + webapi.output
                time.sleep(0.2)
        yield s
    finally:
        robot.close()


# ----------------------------------------------------------------------------- raw clients


class RawClient:
    """A course's socket client: GET, then cut the body at each ``--frame``."""

    def __init__(self, port: int, version: str = "1.1", path: str = "/camera/get", timeout: float = 20.0) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.sock.sendall(f"GET {path} HTTP/{version}\r\nHost: 127.0.0.1\r\n\r\n".encode())
        self.buffer = b""
        while b"\r\n\r\n" not in self.buffer:
            self._recv()
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        self.status_line = lines[0]
        self.headers = {k.strip().lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}

    def _recv(self) -> None:
        data = self.sock.recv(65536)
        if not data:
            raise EOFError("the server closed the connection")
        self.buffer += data

    def jpeg(self) -> tuple[bytes, float]:
        """The next JPEG as the course code cuts it, and when its last byte arrived (monotonic)."""
        while True:
            start = self.buffer.find(b"--frame")
            end = self.buffer.find(b"--frame", start + 1) if start >= 0 else -1
            if end >= 0:
                part, self.buffer = self.buffer[start:end], self.buffer[end:]
                return part.split(b"\r\n\r\n", 1)[1].removesuffix(b"\r\n"), time.monotonic()
            self._recv()

    def close(self) -> None:
        self.sock.close()


def decode(data: bytes) -> np.ndarray:
    frame = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert frame is not None, f"not a JPEG: {data[:40]!r}...{data[-10:]!r}"
    return frame


def rss_kib(proc: Proc) -> int:
    for line in Path(f"/proc/{proc.popen.pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.mark.parametrize("version", ["1.1", "1.0"])
def test_raw_socket_client_cuts_decodable_jpegs_at_the_capture_rate(stack, version):
    client = RawClient(stack.stream_port, version)
    try:
        assert client.status_line == f"HTTP/{version} 200 OK"
        assert client.headers["content-type"] == "multipart/x-mixed-replace; boundary=frame"
        # The body ends with the connection, as the old server's: no length, no chunks.
        assert "transfer-encoding" not in client.headers and "content-length" not in client.headers
        assert client.buffer == b"" or client.buffer.startswith(HEAD[:len(client.buffer)])
        cam = stack.robot.config.camera
        first, _ = client.jpeg()
        assert decode(first).shape == (cam.image_height, cam.image_width, 3)
        start, count = time.monotonic(), 0
        while time.monotonic() - start < 3.0:
            data, _ = client.jpeg()
            assert data[:2] == b"\xff\xd8" and data[-2:] == b"\xff\xd9"
            assert decode(data).std() > 10  # a picture of the arena, not a blank frame
            count += 1
        # The camera captures at 15 Hz; camera/image comes at 0.5 Hz. A loaded machine renders
        # slower, so ask for a third of the capture rate: far above the thumbnails'.
        assert count / 3.0 > cam.fps / 3, f"{count} frames in 3 s"
    finally:
        client.close()


def test_one_shot_client_gets_one_jpeg_per_request(stack):
    """As a client written against a course simulator: requests.get in a loop, 0.1 s timeout.
    The first request asks the camera; the next are answered from the frames the web API
    follows since. A busy test machine may stall a request past 0.1 s now and then (the course
    client then shows that frame black): most must come through, with new frames."""
    session = requests.Session()
    url = stack.url("/camera/get", stack.frame_port)
    assert session.get(url, timeout=10).status_code == 200
    stamps, timeouts = [], 0
    while len(stamps) < 15:
        try:
            r = session.get(url, timeout=0.1)
        except requests.Timeout:
            timeouts += 1
            assert timeouts <= 15, f"{timeouts} of {len(stamps) + timeouts} requests took over 0.1 s"
            continue
        assert r.status_code == 200 and r.headers["Content-Type"] == "image/jpeg"
        assert int(r.headers["Content-Length"]) == len(r.content)
        stamps.append(int(r.headers["X-Frame-Stamp"]))
        assert decode(r.content).shape == (240, 320, 3)
        time.sleep(0.07)
    assert len(set(stamps)) >= 5, "one-shot requests keep getting the same frame"
    assert time.time_ns() - stamps[-1] < 5e9  # a frame of now, not one kept from long ago
    # /camera/frame answers one JPEG whatever camera_get says.
    r = requests.get(stack.url("/camera/frame"), timeout=5)
    assert r.status_code == 200 and decode(r.content).shape == (240, 320, 3)


def test_opencv_videocapture_reads_the_stream(stack):
    capture = cv2.VideoCapture(stack.url("/camera/get"))
    try:
        assert capture.isOpened()
        for _ in range(5):
            ok, frame = capture.read()
            assert ok and frame.shape == (240, 320, 3)
    finally:
        capture.release()


async def test_intrinsics_are_the_calibration_scaled_to_the_http_size(stack):
    r = requests.get(stack.url("/camera/info"), timeout=5)
    assert r.status_code == 200 and r.headers["Content-Type"].startswith("application/json")
    info = r.json()
    assert (info["width"], info["height"]) == (320, 240)
    assert (info["capture_width"], info["capture_height"]) == (640, 480)
    assert info["fx"] == pytest.approx(505.6 / 2) and info["fy"] == pytest.approx(504.9 / 2)
    # Pixel centres: the capture's pixel (0.5, 0.5) is half way into the small image's first pixel.
    assert info["cx"] == pytest.approx((322.4 + 0.5) / 2 - 0.5) and info["cy"] == pytest.approx((241.7 + 0.5) / 2 - 0.5)
    assert info["dist_coeffs"] == pytest.approx([0.08, -0.2, 0.001, -0.002, 0.1])
    assert info["camera_matrix"] == pytest.approx([info["fx"], 0, info["cx"], 0, info["fy"], info["cy"], 0, 0, 1])
    assert info["source"].endswith("camera.yaml")
    async with stack.robot.node("tester") as node:  # the same on the bus
        on_bus: m.CameraInfo = await node.query(keys.CAMERA_INFO, timeout=5)
    assert json.loads(json.dumps(info)) == {f: getattr(on_bus, f) for f in on_bus.__struct_fields__}


def test_scaled_intrinsics_project_where_the_resized_image_shows_a_point():
    small = CALIBRATED.scaled(320, 240)
    point = np.array([[[0.3, -0.1, 1.5]]])
    big_px, _ = cv2.projectPoints(point, np.zeros(3), np.zeros(3), CALIBRATED.camera_matrix, CALIBRATED.dist_coeffs)
    small_px, _ = cv2.projectPoints(point, np.zeros(3), np.zeros(3), small.camera_matrix, small.dist_coeffs)
    # cv2.resize by 1/2 maps the capture's pixel u to (u + 0.5) / 2 - 0.5.
    assert small_px.ravel() == pytest.approx((big_px.ravel() + 0.5) / 2 - 0.5, abs=1e-9)


# ----------------------------------------------------------------------------- costs nothing unwatched


async def test_camera_frames_flow_only_while_someone_watches(stack):
    """webapi subscribes to camera/frames only while an HTTP client watches (seen as Zenoh's
    matching status of a publisher on that key: it matches any subscriber)."""
    async with stack.robot.node("tester") as node:
        probe = node.publisher(keys.FRAMES)

        async def matched(want: bool) -> None:
            deadline = time.monotonic() + 10
            while probe.matched != want:
                assert time.monotonic() < deadline, f"camera/frames matched is not {want}"
                await asyncio.sleep(0.02)

        await matched(False)
        client = await asyncio.to_thread(RawClient, stack.stream_port)
        await asyncio.to_thread(client.jpeg)
        await matched(True)
        client.close()
        await matched(False)


# ----------------------------------------------------------------------------- hostile clients


def never_reading(port: int) -> socket.socket:
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.sendall(b"GET /camera/get HTTP/1.1\r\nHost: x\r\n\r\n")
    return sock


TCP_ESTABLISHED = 1


def tcp_state(sock: socket.socket) -> int:
    """The first field of Linux's struct tcp_info: the connection's state."""
    return sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)[0]


def test_clients_that_never_read_cost_bounded_memory_and_do_not_slow_others(stack):
    reader = RawClient(stack.stream_port)
    stalled: list[socket.socket] = []
    try:
        reader.jpeg()
        before = rss_kib(stack.webapi)
        stalled = [never_reading(stack.stream_port) for _ in range(MAX_WATCHERS - 1)]
        time.sleep(0.5)
        # One more than the limit is refused, in one line.
        extra = RawClient(stack.stream_port)
        assert extra.status_line.endswith("503 Service Unavailable")
        extra.close()
        start, count = time.monotonic(), 0
        while time.monotonic() - start < STALL_S - 1:  # the stalled clients are all still there
            decode(reader.jpeg()[0])
            count += 1
        assert count / (STALL_S - 1) > stack.robot.config.camera.fps / 3, f"{count} frames in {STALL_S - 1} s"
        grown = rss_kib(stack.webapi) - before
        assert grown < 16 * 1024, f"webapi grew {grown} KiB with {len(stalled)} clients that never read"
        # After STALL_S without taking anything, each is disconnected (seen without reading, which
        # would make it a reader again: the kernel's TCP state of the socket).
        deadline = time.monotonic() + STALL_S + 30
        while any(tcp_state(sock) == TCP_ESTABLISHED for sock in stalled):
            assert time.monotonic() < deadline, ("clients that never read are still connected",
                                                 [tcp_state(s) for s in stalled], stack.webapi.output[-2000:])
            time.sleep(0.2)
        decode(reader.jpeg()[0])  # and the reader still gets frames
        assert "Traceback" not in stack.webapi.output, stack.webapi.output[-3000:]
    finally:
        reader.close()
        for sock in stalled:
            sock.close()


@pytest.mark.parametrize("reset", [False, True])
def test_a_client_leaving_mid_part_harms_nobody(stack, reset):
    other = RawClient(stack.stream_port)
    try:
        for _ in range(3):
            leaver = RawClient(stack.stream_port, "1.0")
            while len(leaver.buffer) < len(HEAD) + 100:
                leaver._recv()
            if reset:  # an RST, as a killed program's socket
                leaver.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            leaver.close()
            decode(other.jpeg()[0])
        for _ in range(10):
            decode(other.jpeg()[0])
        assert stack.webapi.alive()
        assert "Traceback" not in stack.webapi.output, stack.webapi.output[-3000:]
    finally:
        other.close()


async def test_bad_payloads_on_camera_frames_are_dropped_in_a_line(stack):
    client = await asyncio.to_thread(RawClient, stack.stream_port)
    try:
        await asyncio.to_thread(client.jpeg)
        async with stack.robot.node("tester") as node:
            for payload in (b"\x00garbage", b'{"stamp": "now"}', b"\x81\xa4data\xc0"):
                for _ in range(20):  # a flood: still one line a second or so
                    node.session.put(node.key(keys.FRAMES), payload)
            for _ in range(10):
                decode((await asyncio.to_thread(client.jpeg))[0])
        deadline = time.monotonic() + 10
        while f"icefloe/{stack.robot.name}/camera/frames" not in stack.webapi.output:
            assert time.monotonic() < deadline, stack.webapi.output[-2000:]
            await asyncio.sleep(0.1)
        assert stack.webapi.output.count("camera/frames") <= 10 and "Traceback" not in stack.webapi.output
    finally:
        client.close()


def test_head_answers_the_headers_and_holds_nothing(stack):
    for _ in range(MAX_WATCHERS + 1):
        r = requests.head(stack.url("/camera/get"), timeout=5)
        assert r.status_code == 200 and r.headers["Content-Type"].startswith("multipart/x-mixed-replace")
    client = RawClient(stack.stream_port)  # no watcher slot was kept
    try:
        assert client.status_line == "HTTP/1.1 200 OK"
    finally:
        client.close()


@pytest.mark.parametrize("query", ["?%ff%fe=%00", "?value=" + "9" * 4000, "?group=1&group=x", "?;;&&==",
                                   "?\u00e9t\u00e9=1", "?" + "&" * 1000])
def test_bad_query_strings_are_ignored_as_the_old_server_did(stack, query):
    for port, path in ((stack.frame_port, "/camera/get"), (stack.stream_port, "/camera/frame"),
                       (stack.stream_port, "/camera/info")):
        r = requests.get(stack.url(path, port) + query, timeout=5)
        assert r.status_code == 200, (path, query, r.text)
    client = RawClient(stack.stream_port, path="/camera/get" + requests.utils.requote_uri(query))
    try:
        assert client.status_line == "HTTP/1.1 200 OK"
        decode(client.jpeg()[0])
    finally:
        client.close()
    # Raw bytes that are not HTTP (a non-ASCII request line): 400, and the next client is served.
    bad = RawClient(stack.stream_port, path="/camera/get" + query)
    bad.close()
    assert bad.status_line.endswith(" 400 Bad Request") or query.isascii(), bad.status_line
    assert "Traceback" not in stack.webapi.output + stack.oneshot.output


# ----------------------------------------------------------------------------- config and calibrate


def test_calibrate_says_what_it_wrote_for_which_size(tmp_path):
    note = sizes_note(CALIBRATED, config_mod.load("sim"))
    assert note.startswith("for 640x480 frames (the camera's capture size, camera/snapshot); the 320x240 JPEGs")
    assert "fx 252.8 px  fy 252.4 px  cx 160.9 px  cy 120.6 px" in note and "/camera/info" in note


@pytest.mark.parametrize("value", ['"single"', "1"])
def test_a_bad_camera_get_starts_nothing_and_says_why_in_one_line(tmp_path, value):
    path = tmp_path / "bad.toml"
    path.write_text(f'extends = "{SIM_CONFIG}"\n[webapi]\nport = {free_port()}\ncamera_get = {value}\n')
    done = subprocess.run([sys.executable, "-m", "icefloe.services.webapi", "--config", str(path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode != 0 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and "webapi.camera_get" in done.stderr, done.stderr


# ----------------------------------------------------------------------------- access control


def test_a_robot_with_access_control_streams_to_anyone(make_robot):
    """The camera routes only read: on a robot with access control they answer without a login,
    or with a wrong one, and the stream's subscription gets through the guarded router."""
    port = free_port()
    robot = make_robot(f'[webapi]\nhost = "127.0.0.1"\nport = {port}\n', access_control=True)
    for service in ("sim", "camera", "webapi"):
        robot.start(service)
    deadline = time.monotonic() + 90
    while True:
        with contextlib.suppress(requests.RequestException):
            if requests.get(f"http://127.0.0.1:{port}/camera/frame", timeout=5).status_code == 200:
                break
        assert time.monotonic() < deadline, "no frame from the simulated camera:\n" + robot.procs[-1].output
        time.sleep(0.2)
    for auth in (None, ("nobody", "wrong")):
        info = requests.get(f"http://127.0.0.1:{port}/camera/info", auth=auth, timeout=5)
        assert info.status_code == 200 and info.json()["width"] == 320
        with requests.get(f"http://127.0.0.1:{port}/camera/get", auth=auth, stream=True, timeout=10) as r:
            assert r.status_code == 200 and "Transfer-Encoding" not in r.headers
            body = b""
            for chunk in r.raw.stream(4096):
                body += chunk
                if body.count(b"--frame") >= 4:
                    break
        for part in body.split(b"--frame")[1:3]:
            decode(part.split(b"\r\n\r\n", 1)[1].removesuffix(b"\r\n"))
