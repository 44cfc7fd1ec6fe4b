"""hwbridge's side of the lab's emergency stop (``lab/stop``, ``cmd/release``; services/hwbridge/hold.py),
on real shared memory without a cycle: a hold refuses every motion command until it is released,
nothing issued before a release drives after it, only the TA releases unless it allowed the
owner, and the hold outlives hwbridge. Pure and fast (about a second); the same on real processes
in a lab is tests/test_lab_stop.py."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from icefloe.config import RobotConfig
from icefloe.errors import NotConfirmed
from icefloe.ordering import Origin
from icefloe.schemas import messages as m
from icefloe.services.hwbridge.bridge import Bridge
from icefloe.services.hwbridge.hold import HoldState
from icefloe.services.hwbridge.shm import STATE_FIELDS, Shared

S = 1_000_000_000


@pytest.fixture
def shared():
    s = Shared.create()
    yield s
    s.close()


def confirm(shared: Shared, number: int) -> None:
    """The cycle's word: stop ``number`` confirmed by the board."""
    values: list[float | int] = [0] * len(STATE_FIELDS)
    values[STATE_FIELDS.index("stop_confirmed")] = number
    values[STATE_FIELDS.index("sample_ns")] = time.monotonic_ns()
    shared.write_state(values)


def student(seq: int, stamp_s: float) -> Origin:
    """A command of the student's program "s", numbered ``seq``, issued at ``stamp_s`` on its clock."""
    return Origin.of(time.monotonic_ns(), "s", seq, int(stamp_s * S))


def ta(seq: int, stamp_s: float) -> Origin:
    return Origin.of(time.monotonic_ns(), "ta", seq, int(stamp_s * S))


def driving(shared: Shared) -> bool:
    """What the cycle reads: targets, and no stop latched."""
    left, right, _fresh, stopped, _epoch, _seq = shared.read_commands()
    return (left, right) != (0.0, 0.0) and not stopped


async def test_a_hold_refuses_every_motion_command_until_the_ta_releases_it(shared, tmp_path) -> None:
    bridge = Bridge(RobotConfig(), shared, logging.getLogger("test"), tmp_path / "hold.json")
    assert bridge.command(0.1, 0.1, "cmd/wheels", student(1, 100.0)) and driving(shared)
    answer = bridge.lab_stop(m.LabStop(action="hold", reason="see me"), ta(1, 5000.0))
    assert not driving(shared)  # latched on the caller's thread, before any answer
    confirm(shared, bridge.stop_seq)
    done = await asyncio.wait_for(answer, 1.0)
    assert done.confirmed and done.held and done.detail == ""
    # The student's program keeps driving: every kind of motion command is refused, with a reason.
    for seq in range(2, 12):
        assert not bridge.command(0.2, 0.2, "cmd/twist", student(seq, 100.0 + seq))
    motion = await bridge.motion(m.Motion(left=0.2, right=0.2, duration=1.0), student(20, 120.0))
    assert not motion.completed and "held stopped by the lab's TA (see me)" in motion.reason
    assert not bridge.car(m.CarDrive(v=0.2, steer=0.3), student(21, 121.0))  # nor as a car
    bridge.motion_step(0.2, 0.2, bridge.changes)  # a timed motion's step that had not learnt of the hold
    bridge.car_step(time.monotonic_ns())  # nor the virtual car's next step
    assert not driving(shared) and bridge.dropped == 12
    held = bridge.hold.message(1)
    assert held.held and held.reason == "see me" and not held.owner_may_release and held.since > 0
    # The owner may not release it: an error reply naming who may; still held.
    with pytest.raises(NotConfirmed, match="until the lab's TA releases it"):
        await bridge.release(m.Release(), student(30, 130.0))
    assert bridge.hold.held and not bridge.command(0.2, 0.2, "cmd/twist", student(31, 131.0))

    # The TA releases it: the robot stays stopped; a command issued before the release does not
    # drive (it arrives late), the next one issued after it does.
    release = bridge.lab_stop(m.LabStop(action="release"), ta(2, 5010.0))
    confirm(shared, bridge.stop_seq)
    done = await asyncio.wait_for(release, 1.0)
    assert done.confirmed and not done.held and not driving(shared)
    assert not bridge.command(0.2, 0.2, "cmd/twist", Origin(time.monotonic_ns() - 300_000_000))
    assert bridge.command(0.2, 0.2, "cmd/twist", student(40, 140.0)) and driving(shared)
    # A release of a robot that is not held changes nothing: it drives on.
    again = await asyncio.wait_for(bridge.lab_stop(m.LabStop(action="release"), ta(3, 5020.0)), 1.0)
    assert again.confirmed and again.detail == "was not held" and driving(shared)
    # A plain stop stops, and the next command drives again.
    plain = bridge.lab_stop(m.LabStop(action="stop"), ta(4, 5030.0))
    assert not driving(shared)
    confirm(shared, bridge.stop_seq)
    assert (await asyncio.wait_for(plain, 1.0)).confirmed and not bridge.hold.held
    assert bridge.command(0.2, 0.2, "cmd/twist", student(41, 141.0)) and driving(shared)


async def test_the_owner_releases_a_hold_only_where_the_ta_allowed_it(shared) -> None:
    bridge = Bridge(RobotConfig(), shared, logging.getLogger("test"))
    hold = bridge.lab_stop(m.LabStop(action="hold", owner_may_release=True, timeout=0.05), ta(1, 10.0))
    unconfirmed = await asyncio.wait_for(hold, 1.0)  # no cycle confirms it here: said so, in time
    assert not unconfirmed.confirmed and unconfirmed.held and "did not confirm the stop within 0.05 s" in \
        unconfirmed.detail
    assert "until the TA or its owner (cmd/release) releases it" in bridge.hold.refusal()
    released = await bridge.release(m.Release(), student(5, 20.0))
    assert not released.held and not bridge.hold.held
    assert not bridge.command(0.1, 0.1, "cmd/twist", student(4, 19.0))  # issued before the release
    assert bridge.command(0.1, 0.1, "cmd/twist", student(6, 21.0))
    # The TA holds it again, for the TA alone: the owner's release is refused.
    bridge.lab_stop(m.LabStop(action="hold", timeout=0.05), ta(2, 30.0)).close()
    with pytest.raises(NotConfirmed, match="refused"):
        await bridge.release(m.Release(), student(7, 31.0))
    assert bridge.hold.held
    # Not held: the owner's release answers so and changes nothing.
    bridge.lab_stop(m.LabStop(action="release", timeout=0.05), ta(3, 40.0)).close()
    assert not (await bridge.release(m.Release(), student(9, 41.0))).held


async def test_the_hold_outlives_hwbridge(shared, tmp_path) -> None:
    """A hwbridge restarted (its cycle died, `icefloe up` restarts it) comes back held; a file it
    cannot read holds the robot too; a release removes the file."""
    path = tmp_path / "hold.json"
    first = Bridge(RobotConfig(), shared, logging.getLogger("test"), path)
    first.lab_stop(m.LabStop(action="hold", reason="r7", timeout=0.05), ta(1, 10.0)).close()
    assert path.exists()
    second = Bridge(RobotConfig(), shared, logging.getLogger("test"), path)
    assert second.hold.held and second.hold.message(1).reason == "r7"
    left, right, _fresh, stopped, _epoch, _seq = shared.read_commands()
    assert stopped and (left, right) == (0.0, 0.0)
    assert not second.command(0.1, 0.1, "cmd/twist", student(1, 11.0))
    second.lab_stop(m.LabStop(action="release", timeout=0.05), ta(2, 20.0)).close()
    assert not path.exists()
    assert not Bridge(RobotConfig(), shared, logging.getLogger("test"), path).hold.held

    path.write_bytes(b"\x00 not json")
    damaged = HoldState(path)
    assert damaged.held and "unreadable hold.json" in damaged.message(1).reason
    # A folder it cannot write to: the hold holds in memory, and the error is kept to be logged.
    blocked = HoldState(tmp_path / "no such folder" / "hold.json")
    blocked.hold(1, "", False)
    assert blocked.held and "FileNotFoundError" in blocked.error
