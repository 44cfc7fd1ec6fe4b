"""Frame age and rate at an HTTP client of ``/camera/get``, next to the bus's own, and webapi's CPU.

    .venv/bin/python bench/webapi_camera.py [--seconds 10]

Starts `icefloe up` on the simulated robot (on free ports, no viz), then:

* webapi's CPU with no HTTP client (it subscribes to nothing heavy: goal < 0.5 % of a core),
  and the camera's, both over the window;
* the reference: a bus subscriber of ``camera/frames`` (the camera publishes those only while
  someone subscribes), each frame's age = its arrival here - its capture stamp;
* ``/camera/get`` read as a course's raw-socket client reads it, at the same time: each JPEG's
  age = its last byte's arrival - the capture stamp of the same bytes on the bus;
* ``/camera/frame`` asked in a loop (one JPEG each, its stamp in ``X-Frame-Stamp``);
* webapi's and the camera's CPU while the stream is watched.

Ages are wall-clock (both ends on this machine). In simulation the capture stamp is the time of
the simulator's pose the frame was rendered from, so both ages include that pose's age too.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from common import cpu_seconds, free_port, robot_config
from stack_cpu import children

from icefloe import config as config_mod
from icefloe.runtime import Node
from icefloe.schemas import keys


def cpu(pids: list[int]) -> float:
    return sum(cpu_seconds(p) for p in pids)


def percent(groups: tuple[list[int], ...], seconds: float) -> list[float]:
    """CPU of each group of processes over the same ``seconds``, % of one core."""
    before, t0 = [cpu(g) for g in groups], time.monotonic()
    time.sleep(seconds)
    wall = time.monotonic() - t0
    return [100 * (cpu(g) - b) / wall for g, b in zip(groups, before, strict=True)]


def summary(ages_ms: list[float]) -> str:
    if not ages_ms:
        return "no frames"
    ages = sorted(ages_ms)
    p95 = ages[min(len(ages) - 1, int(0.95 * len(ages)))]
    return f"median {statistics.median(ages):5.1f} ms  p95 {p95:5.1f} ms  max {ages[-1]:5.1f} ms  ({len(ages)} frames)"


def stream_client(port: int, arrivals: list[tuple[bytes, int]], stop: threading.Event) -> None:
    """A course's raw-socket client: cut the body at ``--frame``, note each JPEG's arrival."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(b"GET /camera/get HTTP/1.1\r\nHost: robot\r\n\r\n")
        buffer = b""
        while b"\r\n\r\n" not in buffer:
            buffer += sock.recv(65536)
        buffer = buffer.split(b"\r\n\r\n", 1)[1]
        while not stop.is_set():
            start = buffer.find(b"--frame")
            end = buffer.find(b"--frame", start + 1) if start >= 0 else -1
            if end < 0:
                data = sock.recv(65536)
                if not data:
                    return
                buffer += data
                continue
            part, buffer = buffer[start:end], buffer[end:]
            # The part is whole once the next boundary is here; its JPEG ended with the bytes before.
            arrivals.append((part.split(b"\r\n\r\n", 1)[1].removesuffix(b"\r\n"), time.time_ns()))


async def measure(config_path: Path, seconds: float) -> None:
    config = config_mod.load(config_path)
    port = config.webapi.port
    procs = children(config_path)
    webapi, camera = procs.get("webapi", []), procs.get("camera", [])
    async with Node("bench", config) as node:
        await asyncio.sleep(3.0)  # every service settled
        idle = await asyncio.to_thread(percent, (webapi, camera), seconds)
        print(f"no HTTP client, {seconds:.0f} s: webapi {idle[0]:.2f} % of a core (goal < 0.5 %), "
              f"camera {idle[1]:.1f} %")

        stamps: dict[bytes, int] = {}
        bus_ages: list[float] = []
        frames = node.subscribe(keys.FRAMES, latest=False)

        async def follow_bus() -> None:
            async for image in frames:
                now = time.time_ns()
                stamps[image.data] = image.stamp
                bus_ages.append((now - image.stamp) / 1e6)

        bus_task = asyncio.create_task(follow_bus())
        await asyncio.sleep(1.0)
        bus_ages.clear()
        arrivals: list[tuple[bytes, int]] = []
        stop = threading.Event()
        client = threading.Thread(target=stream_client, args=(port, arrivals, stop), daemon=True)
        client.start()
        await asyncio.sleep(1.0)
        arrivals.clear()
        bus_ages.clear()
        watched = await asyncio.to_thread(percent, (webapi, camera), seconds)
        stop.set()
        http_ages = [(t - stamps[data]) / 1e6 for data, t in arrivals if data in stamps]
        wall = seconds
        print(f"one client on /camera/get, {wall:.0f} s: webapi {watched[0]:.1f} %, camera {watched[1]:.1f} %")
        print(f"  frame age on the bus (camera/frames, reference): {summary(bus_ages)}  "
              f"{len(bus_ages) / wall:.1f} frames/s")
        print(f"  frame age at the HTTP client (/camera/get):      {summary(http_ages)}  "
              f"{len(arrivals) / wall:.1f} frames/s ({len(arrivals) - len(http_ages)} not matched)")
        bus_task.cancel()
        frames.close()
        client.join(5)

        one_shot: list[float] = []

        def ask() -> None:
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/camera/frame", timeout=1) as r:
                    r.read()
                    one_shot.append((time.time_ns() - int(r.headers["X-Frame-Stamp"])) / 1e6)
                time.sleep(0.05)

        await asyncio.to_thread(ask)
        print(f"  frame age of /camera/frame (one JPEG a request): {summary(one_shot)}")
    print(f"camera capture rate: {config.camera.fps:.0f} Hz; camera/image (the bus's thumbnails): "
          f"{config.camera.image_rate_hz:.0f} Hz; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=10.0, help="length of each measuring window, s")
    args = p.parse_args()
    config = robot_config(Path(tempfile.mkdtemp()), "cambench",
                          f'[webapi]\nhost = "127.0.0.1"\nport = {free_port()}\n')
    up = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "up", str(config), "--no-viz"],
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        port = config_mod.load(config).webapi.port
        while True:  # up once the camera's frames come over HTTP
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/camera/frame", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline or up.poll() is not None:
                sys.exit("the simulated robot did not come up")
            time.sleep(0.5)
        asyncio.run(measure(config, args.seconds))
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, signal.SIGKILL)


if __name__ == "__main__":
    main()
