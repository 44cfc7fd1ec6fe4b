"""Access control: anyone may read a robot, only its own credentials may command it."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest
from conftest import ROOT, Robot

from icefloe import config as config_mod
from icefloe import ros2
from icefloe.credentials import make, read
from icefloe.errors import NotReachable
from icefloe.router import access_control, permits
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m


def session(robot: Robot, user: str = "", password: str = "") -> Node:
    """A laptop's session: with the given credentials, or none at all."""
    zenoh = msgspec.structs.replace(robot.config.zenoh, user=user, password=password, access_control=False,
                                    credentials="")
    return Node("laptop", msgspec.structs.replace(robot.config, zenoh=zenoh), retry=False, announce=False)


async def reaches(sender: Node, sub, topic, message) -> bool:
    """Does ``message`` from ``sender`` arrive at ``sub``? (a few tries, then a second of silence)"""
    pub = sender.publisher(topic)
    await asyncio.sleep(0.3)
    for _ in range(3):
        pub.put(message)
        await asyncio.sleep(0.05)
    try:
        await asyncio.wait_for(sub.__anext__(), 1.0)
        return True
    except TimeoutError:
        return False


async def test_only_the_robots_own_credentials_command_it(make_robot, tmp_path: Path) -> None:
    robot = make_robot(access_control=True)
    own = read(robot.credentials_path)
    other_path, _ = make(tmp_path / "other.credentials", "other-robot")
    other = read(other_path)
    assert robot.config.zenoh.user == own.user  # the robot's services use its credentials

    async with robot.node("hwbridge-stand-in") as service:
        twist = service.subscribe(keys.TWIST)
        car = service.subscribe(keys.CAR)
        pose = service.publisher(keys.ODOM_POSE)
        async with session(robot) as guest:  # no credentials: the read-only guest
            poses = guest.subscribe(keys.ODOM_POSE)
            await asyncio.sleep(0.3)
            pose.put(m.Pose(stamp=1, x=1.0, y=0.0, theta=0.0))
            assert (await asyncio.wait_for(poses.__anext__(), 3)).x == 1.0
            assert not await reaches(guest, twist, keys.TWIST, m.Twist(v=0.2, w=0.0))
            assert not await reaches(guest, car, keys.CAR, m.CarDrive(v=0.2, steer=0.3))  # nor drive it as a car
            with pytest.raises(NotReachable):  # nor call its queryables
                await guest.query(keys.INFO, timeout=1.0)
            token = guest.session.liveliness().declare_token(keys.alive_key(robot.name, "fake"))
            await asyncio.sleep(0.3)  # nor pretend to be one of its services
            assert keys.alive_key(robot.name, "fake") not in await service.alive()
            assert keys.alive_key(robot.name, "hwbridge-stand-in") in await service.alive()
            token.undeclare()
        with pytest.raises(NotReachable):  # another robot's credentials: not a user of this robot
            async with session(robot, other.user, other.password):
                pass
        async with session(robot, own.user, own.password) as owner:
            assert await reaches(owner, twist, keys.TWIST, m.Twist(v=0.1, w=0.0))
            assert await reaches(owner, car, keys.CAR, m.CarDrive(v=0.1, steer=0.3))
        with pytest.raises(NotReachable):
            async with session(robot, own.user, "not the password"):
                pass
        assert robot.router.alive()  # the robot kept running through all of it


def test_cli_commands_with_a_credentials_file(make_robot) -> None:
    robot = make_robot(access_control=True)
    echo = subprocess.Popen([sys.executable, "-m", "icefloe.cli", "echo", "cmd/twist", "--count", "1",
                             "--duration", "10", "--credentials", str(robot.credentials_path)],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT)
    import time

    time.sleep(1.5)
    pub = subprocess.run([sys.executable, "-m", "icefloe.cli", "pub", "cmd/twist", '{"v": 0.1, "w": 0}',
                          "--rate", "5", "--count", "5", "--credentials", str(robot.credentials_path)],
                         capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert pub.returncode == 0, pub.stderr
    out, _ = echo.communicate(timeout=15)
    assert '"v": 0.1' in out


def test_credentials_are_made_once_private_and_never_printed(tmp_path: Path) -> None:
    cfg = tmp_path / "r.toml"
    creds = tmp_path / "secret" / "r9.credentials"
    cfg.write_text(f'extends = "{ROOT}/deploy/robots/sim.toml"\nname = "r9"\n'
                   f'[zenoh]\naccess_control = true\ncredentials = "{creds}"\n')
    run = [sys.executable, "-m", "icefloe.cli", "credentials", str(cfg), "--host", "10.0.0.9"]
    first = subprocess.run(run, capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert first.returncode == 0 and "made" in first.stdout
    made = read(creds)
    assert made.robot == "r9" and made.connect == ["tcp/10.0.0.9:7447"] and len(made.password) >= 20
    assert creds.stat().st_mode & 0o777 == 0o600
    assert made.password not in first.stdout + first.stderr
    again = subprocess.run(run, capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert "kept" in again.stdout and read(creds).password == made.password
    sheet = subprocess.run([*run, "--sheet"], capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert f"password: {made.password}" in sheet.stdout  # only when asked for, to hand over


def test_a_guarded_router_without_credentials_refuses_to_start(tmp_path: Path) -> None:
    cfg = tmp_path / "r.toml"
    cfg.write_text(f'extends = "{ROOT}/deploy/robots/sim.toml"\nname = "r8"\n'
                   f'[zenoh]\nlisten = ["tcp/127.0.0.1:0"]\naccess_control = true\n'
                   f'credentials = "{tmp_path}/missing.credentials"\n')
    res = subprocess.run([sys.executable, "-m", "icefloe.router", "--config", str(cfg)],
                         capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert res.returncode != 0
    assert "access_control is on but there are no credentials" in res.stderr


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is not installed")
async def test_tls_with_the_lab_ca_and_credentials(tmp_path: Path) -> None:
    """The router listens on TLS; a laptop that trusts the lab CA and has the credentials drives it."""
    from conftest import free_port

    make_certificates(tmp_path)
    port = free_port()
    creds, _ = make(tmp_path / "r.credentials", "tlsbot")
    cfg = tmp_path / "r.toml"
    cfg.write_text(
        f'extends = "{ROOT}/deploy/robots/sim.toml"\nname = "tlsbot"\nrun_dir = "{tmp_path}/run"\n'
        f'[zenoh]\nlisten = ["tls/127.0.0.1:{port}"]\nconnect = ["tls/localhost:{port}"]\n'
        f'access_control = true\ncredentials = "{creds}"\n'
        f'tls_certificate = "{tmp_path}/robot.pem"\ntls_private_key = "{tmp_path}/robot.key"\n'
        f'tls_root_ca = "{tmp_path}/ca.pem"\n'
    )
    router = subprocess.Popen([sys.executable, "-m", "icefloe.router", "--config", str(cfg)], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert "listening on tls/" in router.stdout.readline()
        robot_cfg = config_mod.load(cfg)
        async with Node("service", robot_cfg) as service, Node("laptop", robot_cfg, announce=False) as laptop:
            twist = service.subscribe(keys.TWIST)
            assert await reaches(laptop, twist, keys.TWIST, m.Twist(v=0.1, w=0.0))
        untrusting = msgspec.structs.replace(robot_cfg, zenoh=msgspec.structs.replace(robot_cfg.zenoh, tls_root_ca=""))
        with pytest.raises(NotReachable):  # a laptop that does not trust the lab CA cannot connect
            async with Node("laptop", untrusting, retry=False, announce=False):
                pass
    finally:
        router.terminate()
        router.wait(10)


def make_certificates(folder: Path) -> None:
    """A lab CA and a robot certificate for localhost, as docs/lab.md tells a TA to make them."""
    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True)

    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
            "-days", "3650", "-subj", "/CN=icefloe lab CA")
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "robot.key", "-out", "robot.csr",
            "-subj", "/CN=localhost")
    (folder / "san.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    openssl("x509", "-req", "-in", "robot.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", "robot.pem", "-days", "3650", "-extfile", "san.cnf")


# ---------------------------------------------------------------------- ROS 2's keys (docs/ros2.md)


def data_key(namespace: str, topic: str = "cmd_vel", ros_type: str = "geometry_msgs/msg/Twist", domain: int = 0) -> str:
    """A topic's data key in a namespace: ``p1`` -> ``0/p1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_...``."""
    return ros2.Endpoint(domain, f"/{namespace}", f"/{namespace}/{topic}", ros_type, "jazzy").data_key


def node_token(namespace: str, node: str = "teleop") -> str:
    """rmw_zenoh's token of a node (icefloe/ros2.py writes them as design.md shows them)."""
    return ros2.node_token(0, "aac3178e146ba6f1fc6e6a4085e77f21", 0, namespace, node)


def endpoint_token(namespace: str, topic: str, kind: str = "MP") -> str:
    return ros2.endpoint_token(ros2.Endpoint(0, namespace, topic, "geometry_msgs/msg/Twist", "jazzy"), kind,
                               "aac3178e146ba6f1fc6e6a4085e77f21", 0, 1, "teleop")


def test_ros2_keys_are_the_owners_to_put_and_everyones_to_read() -> None:
    """Who may do what with ROS 2's keys, as a lab router with robots p1 and p2 and a TA decides it
    (`permits` reads the very rules the router gets; tests/test_ros2_service.py drives through a real one)."""
    acl = access_control([("p1", "p1"), ("p2", "p2"), ("*", "ta")])
    cmd_vel, odom = data_key("p1"), data_key("p1", "odom", "nav_msgs/msg/Odometry")
    # p1's owner (and its ros2 service, the same login): publish in its namespace, subscribe, read the graph.
    for key in (cmd_vel, odom):
        assert permits(acl, "p1", "put", key), key
    for user in ("p1", "p2", "guest", "ta"):  # everybody reads every robot's topics and ROS 2's graph
        assert permits(acl, user, "declare_subscriber", odom), user
        assert permits(acl, user, "declare_subscriber", "0/**"), user
        assert permits(acl, user, "declare_subscriber", cmd_vel), user  # the service's subscription
        assert permits(acl, user, "liveliness_query", "@ros2_lv/0/**"), user
        assert permits(acl, user, "declare_liveliness_subscriber", "@ros2_lv/0/**"), user
        assert permits(acl, user, "put", odom, flow="egress"), user
        assert permits(acl, user, "liveliness_token", node_token("/p1", "icefloe"), flow="egress"), user
    # Nobody else puts on p1's keys: not the guest, not p2's owner, not the TA (ROS 2 has no stop message).
    for user in ("p2", "guest", "ta", "nobody"):
        assert not permits(acl, user, "put", cmd_vel), user
        assert not permits(acl, user, "delete", cmd_vel), user
    # Wildcards that reach beyond p1's namespace are refused even for p1's owner; in it, the service drops them.
    for key in ("0/**", "0/*/cmd_vel/**", "**", "*/p1/**", "0/p$*/cmd_vel/**", "0/p1$*/**", "0/*/**",
                data_key("p2"), data_key("p10"), "1/p1/cmd_vel/**", "icefloe/p2/cmd/twist"):
        assert not permits(acl, "p1", "put", key), key
    assert permits(acl, "p1", "put", "0/p1/cmd_vel/**")  # its own space: services/ros2 drops a wildcard
    # Nobody subscribes beyond what is public, or asks ROS 2 services (queryables) of a robot.
    for user in ("p1", "guest"):
        assert not permits(acl, user, "declare_subscriber", "**"), user
        assert not permits(acl, user, "query", "0/p1/**"), user
        assert not permits(acl, user, "declare_queryable", "0/p1/**"), user
        assert not permits(acl, user, "liveliness_query", "@ros2_lv/**"), user  # another domain, or all


def test_ros2_liveliness_tokens_name_the_owners_namespace_only() -> None:
    """rmw_zenoh declares a token per node and per publisher or subscription: the owner's tokens must
    name its robot's namespace (as node, or as topic of a node in the root namespace); a token that
    names another robot's namespace is refused, so nobody can fake another robot's node or topics."""
    acl = access_control([("p1", "p1"), ("p2", "p2")])
    mine = [node_token("/p1", "icefloe"), node_token("/p1/arm", "gripper"),
            endpoint_token("/p1", "/p1/odom"), endpoint_token("/p1", "/p1/cmd_vel", "MS"),
            endpoint_token("", "/p1/cmd_vel"), endpoint_token("/p1/arm", "/p1/arm/joint_states")]
    for token in mine:
        assert permits(acl, "p1", "liveliness_token", token), token
        assert not permits(acl, "guest", "liveliness_token", token), token  # the guest declares nothing
        assert not permits(acl, "p2", "liveliness_token", token), token
    # A node in the root namespace (`ros2 topic echo`, teleop_twist_keyboard) names no robot: any owner's.
    assert permits(acl, "p1", "liveliness_token", node_token("", "teleop"))
    assert not permits(acl, "guest", "liveliness_token", node_token("", "teleop"))
    spoofs = [node_token("/p2", "icefloe"), node_token("/p10", "icefloe"), node_token("/p1x", "icefloe"),
              endpoint_token("", "/p2/cmd_vel"), endpoint_token("/p2", "/p1/cmd_vel"),  # a node in p2's name
              endpoint_token("/p1", "/p2/odom"), endpoint_token("/p1", "/rosout"), endpoint_token("", "/cmd_vel"),
              "@ros2_lv/0/**", "@ros2_lv/0/*/0/0/NN/%/*/icefloe", "@ros2_lv/0/*/0/1/MP/%/%/teleop/*/**",
              "@ros2_lv/1/aac3/0/0/NN/%/%p1/icefloe",  # another domain
              keys.alive_key("p2", "ros2")]
    for token in spoofs:
        assert not permits(acl, "p1", "liveliness_token", token), token


def test_ros2_rules_follow_the_robots_config() -> None:
    """A robot's router takes the domain and namespace from its config (`router_config`); a robot whose
    name ROS 2 cannot take and that sets no namespace gets no ROS 2 keys at all."""
    acl = access_control([("pen-1", "u1")], ros2_domain=7, ros2_namespaces={"pen-1": "/lab/pen1"})
    assert permits(acl, "u1", "put", data_key("lab/pen1", domain=7))
    assert not permits(acl, "u1", "put", data_key("lab/pen1"))  # domain 0 is not this robot's
    assert not permits(acl, "u1", "put", "7/lab/**")
    assert permits(acl, "u1", "liveliness_token", "@ros2_lv/7/z/0/0/NN/%/%lab%pen1/icefloe")
    assert not permits(acl, "u1", "liveliness_token", "@ros2_lv/7/z/0/0/NN/%/%lab/icefloe")
    assert permits(acl, "guest", "declare_subscriber", "7/**")
    assert not permits(acl, "guest", "declare_subscriber", "0/**")
    nameless = access_control([("pen-1", "u1")])
    assert not any(permits(nameless, "u1", m, k) for m in ("put", "liveliness_token")
                   for k in ("0/pen-1/cmd_vel/T/H", "@ros2_lv/0/z/0/0/NN/%/%pen-1/icefloe"))
