"""The CLI explains the bus (topics -v, info, services) and catches typos, against real services."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
from conftest import ROOT, Robot
from test_cli import icefloe

from icefloe.graph import parse


def test_the_graph_names_sessions_by_their_tokens() -> None:
    bus = parse([
        ("@/r1/router/publisher/icefloe/sim/odom/pose", b'{"clients": ["a"], "routers": [], "peers": []}'),
        ("@/r1/router/subscriber/icefloe/*/odom/pose", b'{"clients": ["b", "c"], "routers": ["r1"]}'),
        ("@/r1/router/token/icefloe/sim/alive/odometry", b'{"clients": ["a"]}'),
        ("@/r1/router/token/icefloe/lap/alive/viz", b'{"clients": ["b"]}'),
        ("@/r1/router/linkstate/north", b"graph {}"),
    ])
    assert bus.on("icefloe/sim/odom/pose", "publisher") == ["a"]
    assert bus.on("icefloe/sim/odom/pose", "subscriber") == ["b", "c"]  # a wildcard reaches the key
    assert [bus.name(z, "sim") for z in ("a", "b", "c")] == ["odometry", "lap/viz", "(unnamed c)"]
    assert bus.keys_declared("icefloe/sim/") == {"icefloe/sim/odom/pose"}


@pytest.fixture
def running(robot: Robot) -> Robot:
    for service in ("info", "sim", "hwbridge", "odometry"):
        robot.start(service)
    deadline = time.monotonic() + 60
    while not {"info", "hwbridge", "odometry"} <= set(icefloe(robot, "status").stdout.split()):
        assert time.monotonic() < deadline, [p.output for p in robot.procs]
        time.sleep(0.5)
    return robot


@pytest.mark.slow
@pytest.mark.timeout(300)  # eight command-line runs: each starts a Python, slow on a busy machine
def test_topics_info_and_services_say_who_does_what(running: Robot) -> None:
    robot = running
    out = icefloe(robot, "topics", "-v", "--duration", "2").stdout
    rows = {line.split()[0]: line for line in out.splitlines()}
    key = f"icefloe/{robot.name}"
    # Every key of the key table is listed, live or not, with its direction and message.
    assert rows[f"{key}/cmd/twist"].split()[1:3] == ["in", "Twist"]
    assert "hwbridge" in rows[f"{key}/cmd/twist"]
    pose = rows[f"{key}/odom/pose"]
    assert pose.split()[1:3] == ["out", "Pose"] and " Hz" in pose and "1 pub" in pose and "odometry ->" in pose
    assert "answered by hwbridge" in rows[f"{key}/cmd/motion"] and "1 qry" in rows[f"{key}/cmd/motion"]
    assert rows[f"{key}/loc/pose"].split()[3] == "-"  # no localizer here: no rate

    info = icefloe(robot, "info", "cmd/motion").stdout
    assert "request: Motion" in info and "duration: float" in info and "Time at full speed plus one ramp, s" in info
    assert "reply: MotionDone" in info and "answered by (1): hwbridge" in info
    info = icefloe(robot, "info", "odom/pose").stdout
    assert "publishers (1): odometry" in info and "theta: float" in info and "rad" in info

    services = icefloe(robot, "services").stdout
    hw = services.split(f"{robot.name}/hwbridge\n", 1)[1].split(f"\n{robot.name}/", 1)[0]
    assert "publishes:" in hw and "hw/wheels" in hw and "cmd/twist" in hw and "answers:" in hw and "cmd/motion" in hw
    assert f"{robot.name}/odometry" in services and f"{robot.name}/info" in services


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_typos_and_wrong_uses_get_the_closest_keys_and_a_failing_exit(running: Robot) -> None:
    robot = running
    echo = icefloe(robot, "echo", "odom/posee", "--duration", "2")
    assert echo.returncode == 1 and "did you mean odom/pose" in echo.stderr and "nothing on" in echo.stderr
    hz = icefloe(robot, "hz", "nonsense/key", "--duration", "1.5")
    assert hz.returncode == 1 and "not a key of the key table" in hz.stderr
    once = icefloe(robot, "echo", "odom/pose", "--once")
    assert once.returncode == 0 and set(json.loads(once.stdout)) >= {"x", "y", "theta"}
    two = icefloe(robot, "echo", "hw/wheels", "-n", "2")
    assert two.returncode == 0 and len(two.stdout.splitlines()) == 2
    other = icefloe(robot, "echo", "odom/pose", "--robot", "nosuch", "--duration", "1")
    assert other.returncode == 1 and f"robots alive here: {robot.name}" in other.stderr

    refused = icefloe(robot, "pub", "odom/pose", '{"stamp": 1, "x": 9, "y": 0, "theta": 0}')
    assert refused.returncode == 2 and "state the robot publishes" in refused.stderr and "--force" in refused.stderr
    typo = icefloe(robot, "pub", "cmd/twst", '{"v": 0.1, "w": 0}')
    assert typo.returncode == 2 and "did you mean cmd/twist" in typo.stderr
    bad = icefloe(robot, "query", "cmd/motion", '{"distance": 0.2}')
    assert bad.returncode == 2 and "unknown field `distance`" in bad.stderr
    assert "left: float" in bad.stderr and "duration: float" in bad.stderr and "m/s" in bad.stderr
    # --force publishes an output key (a stand-in for a service in a test): it arrives.
    listener = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "echo", "power/shutdown", "--once",
                                 "--config", str(robot.config_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, cwd=ROOT)
    assert "no publisher is declared" in listener.stderr.readline()  # it listens (no power service here)
    forced = icefloe(robot, "pub", "power/shutdown", '{"stamp": 5, "reason": "test"}', "--force")
    assert forced.returncode == 0, forced.stderr
    out, _ = listener.communicate(timeout=20)
    assert json.loads(out)["reason"] == "test"
