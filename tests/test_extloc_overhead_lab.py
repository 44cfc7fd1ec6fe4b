"""The lab's external localizer in a simulated lab: real processes throughout.

A lab router (``icefloe router --lab``), two simulated robots (``sim`` + ``hwbridge``, each with
its own router joined to the lab), and the lab's localizer (``services.extloc``) logged in with
the lab's own credentials, rendering the overhead camera from the robots' ``sim/truth``. Checked:
each robot's pose on its own ``extloc/pose`` against the simulator's truth, on the lab router and
on the robot's own router; a robot carried out
of view gets no pose; the old localiser's HTTP API read by the course's pibot_client, unchanged
(tests/course_clients.py): the old square's frame, degrees, zeros for an unknown group and for the robot out
of view, hostile query strings; and a student who forges an external pose, their own robot's or another's, on the
lab router or their robot's own router, with or without wildcards, is refused. Takes 30-60 s.
"""

from __future__ import annotations

import asyncio
import json
import math
import sys
import time
from pathlib import Path

import pytest
import requests
from conftest import ROOT
from course_clients import localiser_client

from icefloe import credentials
from icefloe.runtime import MSGPACK, Node
from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m

sys.path.insert(0, str(ROOT / "bench"))
from common import free_port
from lab_harness import Lab, Proc
from lab_scale import guest_config, laptop_config

STARTS = [(0.4, 0.3, 1.0), (1.6, -0.85, 0.0)]
"""Where the two robots stand: the second near the east edge of the view, facing it."""


def robot_toml(i: int, _name: str) -> str:
    x, y, theta = STARTS[i]
    # The harness's robot config puts this right after its own [sim] table: these lines go into it.
    return (f"start_x = {x}\nstart_y = {y}\nstart_theta = {theta}\n\n"
            f"[extloc]\nmarker_id = {20 + i}\nmarker_size = 0.16\nmarker_height = 0.12\n")


def start_localizer(lab: Lab, http_port: int) -> Proc:
    """The lab's own credentials (its robot: the lab config's name) and the localizer's config."""
    creds = lab.lab_dir / "lab.credentials"
    config = lab.root / "extloc.toml"
    robots = json.dumps([str(lab.configs[name]) for name in lab.names])
    config.write_text(f'name = "lab"\nrun_dir = "{lab.root / "run-extloc"}"\n\n'
                      f'[overhead]\nrobots = {robots}\nfps = 15.0\nhttp_host = "127.0.0.1"\n'
                      f"http_port = {http_port}\n\n"
                      f'[zenoh]\nlisten = []\nconnect = ["{lab.endpoint}"]\ncredentials = "{creds}"\n')
    return Proc("extloc", [sys.executable, "-m", "icefloe.services.extloc", "--config", str(config)],
                lab.root / "extloc.log")


def answered(call, *args):
    """``call(*args)`` of pibot_client, again while it says None: its timeout is 1 s (it prints "Timed
    out" and returns None), which a localizer process on a loaded machine may miss now and then."""
    deadline = time.monotonic() + 10
    while (answer := call(*args)) is None:
        assert time.monotonic() < deadline, f"{call.__name__}{args}: no answer within 1 s for 10 s"
    return answer


class Watch:
    """The guest's view: every robot's external poses and truths, as they arrive."""

    def __init__(self, guest: Node, names: list[str]) -> None:
        self.poses: dict[str, list[tuple[float, m.ExternalPose]]] = {n: [] for n in names}
        self.truth: dict[str, m.Truth] = {}
        self.tasks = [asyncio.create_task(self._poses(guest, n)) for n in names]
        self.tasks += [asyncio.create_task(self._truth(guest, n)) for n in names]

    async def _poses(self, guest: Node, name: str) -> None:
        async for pose in guest.subscribe(keys.EXTLOC_POSE, robot=name, latest=False, maxsize=1000):
            self.poses[name].append((time.monotonic(), pose))

    async def _truth(self, guest: Node, name: str) -> None:
        async for truth in guest.subscribe(keys.TRUTH, robot=name):
            self.truth[name] = truth

    async def until(self, what: str, check, timeout: float = 45.0) -> None:
        deadline = time.monotonic() + timeout
        while not check():
            assert time.monotonic() < deadline, f"waited {timeout} s for {what}"
            await asyncio.sleep(0.1)

    def close(self) -> None:
        for task in self.tasks:
            task.cancel()


@pytest.mark.slow
@pytest.mark.timeout(300)  # 30 s alone; a loaded machine starts five routers and services much slower
async def test_overhead_localizer_in_a_simulated_lab(tmp_path: Path) -> None:
    http_port = free_port()
    with Lab(tmp_path, robots=2, mesh=True, services=("sim", "hwbridge"), extra_toml=robot_toml) as lab:
        credentials.make(lab.lab_dir / "lab.credentials", "lab", [lab.endpoint])
        lab.start_router()
        lab.start_robots()
        localizer = start_localizer(lab, http_port)
        lab.procs.setdefault("lab", []).append(localizer)
        a, b = lab.names
        async with Node("classmate", guest_config(lab.endpoint), announce=False) as guest:
            watch = Watch(guest, lab.names)
            try:
                await watch.until("both robots' external poses", lambda: all(watch.poses.values()), 60.0)

                # Each robot's pose, against the simulator's truth (both stand still).
                for name in lab.names:
                    _, pose = watch.poses[name][-1]
                    truth = watch.truth[name]
                    assert math.hypot(pose.x - truth.x, pose.y - truth.y) < 0.01, (name, pose, truth)
                    assert abs(math.remainder(pose.theta - truth.theta, math.tau)) < math.radians(1.5)
                    assert pose.covariance[0] < 0.01**2 and pose.side_px > 15

                # A laptop plugged straight into robot A's own router reads A's external pose too:
                # the lab router passes it over A's lab link.
                async with Node("laptop", guest_config(lab.endpoints[a]), announce=False) as local:
                    mine = local.subscribe(keys.EXTLOC_POSE, robot=a)
                    assert (await asyncio.wait_for(anext(mine), 30)).x == pytest.approx(STARTS[0][0], abs=0.01)

                # The old localiser's API, read by the course's own client: group 1 is the first robot,
                # in the old square's frame (its corner at the world's (-0.5, -0.5)) and in degrees.
                bot = localiser_client("127.0.0.1", http_port, lab.root)
                x, y, theta = answered(bot.getLocalizerPose, 1)
                assert math.hypot(x - (STARTS[0][0] + 0.5), y - (STARTS[0][1] + 0.5)) < 0.01, (x, y)
                assert abs(theta - math.degrees(STARTS[0][2])) < 1.5, theta
                x, y, theta = answered(bot.getLocalizerPose, 2)  # outside the old square: its frame still
                assert math.hypot(x - (STARTS[1][0] + 0.5), y - (STARTS[1][1] + 0.5)) < 0.01 and abs(theta) < 1.5
                assert answered(bot.getLocalizerPose, 7) == (0.0, 0.0, 0.0)  # no robot: zeros, no KeyError
                for query in ("group=abc", "group=-1", "group=" + "9" * 3000, ""):
                    answer = requests.get(f"http://127.0.0.1:{http_port}/pose/get?{query}", timeout=5)
                    assert answer.status_code == 200 and answer.json()["pose"] == {"x": 0, "y": 0, "theta": 0}
                    assert "group" in answer.json()["error"], answer.text
                picture = answered(bot.getLocalizerImage)
                assert picture.shape == (500, 500, 3)  # the old square's, 4 mm a pixel

                # Forgeries: robot A's owner, on the lab router and on A's own router, every form.
                await forge(lab, a, [a, b])
                await asyncio.sleep(2.0)  # time for a forgery to arrive, had it got through
                for name in lab.names:
                    assert not [p for _, p in watch.poses[name] if p.x == 9.5], f"a forged pose reached {name}"

                # Robot B leaves the camera's view: then it gets no pose at all. The lab's walls keep a
                # driven robot inside the view, so its owner carries it out, through the simulator's
                # controls (sim/control `place`: out of the arena, east of the camera's view).
                async with Node("laptop", laptop_config(lab.credentials_file(b), lab.endpoint),
                                announce=False) as owner:
                    await owner.query(keys.SIM_CONTROL, m.SimControl(action="place", x=2.9, y=-0.85, theta=0.0),
                                      timeout=10.0, robot=b)
                    await watch.until("robot B out of view", lambda: watch.truth[b].x > 2.45)
                gone = time.monotonic()
                before_a = len(watch.poses[a])
                await watch.until("more poses of robot A", lambda: len(watch.poses[a]) > before_a + 10)
                late = [p for t, p in watch.poses[b] if t > gone + 0.5]
                assert late == [], f"robot B, out of view, still got {len(late)} poses: {late[:1]}"
                # The old API forgets a robot a second after its last pose (it was carried out a moment
                # ago): then 0, 0, 0, as the old localiser said when it saw no robot.
                deadline = time.monotonic() + 10
                while answered(bot.getLocalizerPose, 2) != (0.0, 0.0, 0.0):
                    assert time.monotonic() < deadline, "/pose/get still answers for robot B, out of view for 10 s"
                    await asyncio.sleep(0.2)
                # Robot A is still served.
                assert answered(bot.getLocalizerPose, 1)[0] == pytest.approx(STARTS[0][0] + 0.5, abs=0.01)
            finally:
                watch.close()
        assert localizer.alive(), localizer.tail()
        log = localizer.log.read_text()
        assert "overhead camera found from floor markers" in log
        assert "/pose/get?group=7: no robot has group 7 (groups: 1, 2)" in log
        assert f"/pose/get?group=2: robot {b} not seen by the overhead camera" in log
    assert lab.killed == [], "these did not stop on SIGINT"


async def forge(lab: Lab, owner: str, targets: list[str]) -> None:
    """Put forged external poses (x = 9.5) with ``owner``'s credentials, on the lab router and on
    the owner's robot's own router, on each target's key and on wildcards that reach them."""
    fake = codec.encode(m.ExternalPose(stamp=time.time_ns(), x=9.5, y=0.0, theta=0.0, covariance=[0.0] * 9))
    exprs = [keys.key(t, keys.EXTLOC_POSE) for t in targets]
    exprs += ["icefloe/*/extloc/pose", f"icefloe/{owner}/extloc/*", f"icefloe/{owner}/**", "icefloe/**",
              f"icefloe/{owner}/ext$*/pose", "**"]
    for endpoint in (lab.endpoint, lab.endpoints[owner]):
        config = laptop_config(lab.credentials_file(owner), endpoint)
        async with Node("forger", config, announce=False) as forger:
            for _ in range(3):
                for expr in exprs:
                    forger.session.put(expr, fake, encoding=MSGPACK)
                await asyncio.sleep(0.2)


def test_overhead_localizer_refuses_a_lab_without_robots(tmp_path: Path) -> None:
    import subprocess

    config = tmp_path / "lab.toml"
    config.write_text('name = "lab"\n[overhead]\nrobots = []\n')
    done = subprocess.run([sys.executable, "-m", "icefloe.services.extloc", "--config", str(config)],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 78, done.stderr
    assert "overhead.robots: no robots to look for" in done.stderr
    assert "Traceback" not in done.stderr
