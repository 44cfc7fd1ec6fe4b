"""The lap judge: RVSS "Need 4 Speed"'s lap time, penalties and reward of a track world, from the truth.

    python -m icefloe.services.judge --config deploy/robots/sim.toml
    icefloe echo judge/state

It reads the simulator's truth (``sim/truth``, timed by its ``sim_time``: `timing`) and the
track of ``judge.world`` (else ``sim.world``), scores each lap by the workshop's rules
(`scoring`, docs/judge.md), publishes ``judge/state`` (`JudgeState`) ``judge.rate_hz`` times a
second and ``judge/lap`` (`JudgeLap`) at each lap's end, logs each penalty as one line, and
appends each lap to ``judge.results`` (JSON lines), the lap in progress too when it stops. A
world without a track is one line and exit status 78 (`ConfigError`): `icefloe up` does not
restart it.
"""

from __future__ import annotations

import asyncio
import time

import numpy as np

from icefloe import paths
from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.worldmap import load_world

from .report import RECENT_EVENTS, Results, lap_message, state_message
from .scoring import Event, Judge, Rules, TrackLike
from .timing import TruthTime

MAX_AHEAD_S = 10.0
"""A truth sample stamped further ahead of this machine's clock is refused: one such sample would
otherwise make every true one after it "old" (the simulator stamps with its machine's clock)."""


def track_of(config: RobotConfig) -> TrackLike:
    """The judged world's track; `ConfigError` naming the world file when it has none."""
    world = load_world(config.judge.world or config.sim.world)
    name = world_path(config.judge.world or config.sim.world)
    if world.track is None:
        raise ConfigError(f"{name}: track: the world has no track to judge (set `track = \"<layout>\"` in the "
                          "world file, or judge.world to a track world such as \"track\")")
    line = world.track.centerline()
    if len(line) < 2 or not np.allclose(line[0], line[-1]):
        raise ConfigError(f"{name}: track: {world.track.name}'s road does not close into a loop: the judge "
                          "times laps, from the start line round to it again")
    return world.track


def world_path(name_or_path: str) -> str:
    """The world file a name means (as `load_world` finds it), for messages."""
    text = name_or_path if "/" in name_or_path or name_or_path.startswith("~") else name_or_path.removesuffix(".toml")
    return str(paths.find("worlds", text, "world file"))


def rules_of(config: RobotConfig) -> Rules:
    g, j = config.geometry, config.judge
    return Rules(wheel_track=g.track, wheel_diameter=g.wheel_diameter, radius=g.radius, stop_zone=j.stop_zone,
                 stop_dwell_s=j.stop_dwell_s, stop_tolerance=j.stop_tolerance)


async def main(config: RobotConfig) -> None:
    track = track_of(config)
    judge = Judge(track, rules_of(config))
    results = Results(config.judge.results, config.source)
    recent: list[Event] = []
    clock = TruthTime()
    last_stamp = 0

    async with Node("judge", config) as node:
        state = node.publisher(keys.JUDGE_STATE)
        laps = node.publisher(keys.JUDGE_LAP)

        async def judge_truth() -> None:
            nonlocal last_stamp
            async for truth in node.subscribe(keys.TRUTH, latest=False):
                # (Non-finite numbers never get here: the subscription drops them with a line.)
                if truth.stamp > time.time_ns() + MAX_AHEAD_S * 1e9:
                    node.limited.warning("judge future", "sim/truth: stamp %d is %.0f s ahead of this clock; ignored",
                                         truth.stamp, (truth.stamp - time.time_ns()) / 1e9)
                    continue
                if truth.stamp <= last_stamp:  # an old sample (or another publisher's): time runs forward only
                    node.limited.warning("judge stamp", "sim/truth: stamp %d is not after the last one (%d); ignored",
                                         truth.stamp, last_stamp)
                    continue
                last_stamp = truth.stamp
                t = clock.seconds(truth)
                if t is None:
                    node.limited.warning("judge sim_time", "sim/truth: stamp %d has no sim_time where the ones "
                                         "before had; ignored", truth.stamp)
                    continue
                for event in judge.feed(t, truth.x, truth.y, truth.theta):
                    recent[:] = [*recent[-RECENT_EVENTS + 1:], event]
                    if event.penalty:
                        node.log.warning("lap %d: %s: +%.0f s at x %.2f m, y %.2f m", event.lap, event.text,
                                         event.penalty, event.x, event.y)
                    else:
                        node.log.info("%s", event.text)
                    if event.kind == "lap_end":
                        done = judge.finished[-1]
                        message = lap_message(track.name, done, judge.now, clock.stamp)
                        laps.put(message)
                        results.write(message)

        async def publish_state() -> None:
            period = 1.0 / config.judge.rate_hz
            while True:
                state.put(state_message(judge, recent, clock.stamp))
                await asyncio.sleep(period)

        node.log.info("judging track %s (lap %.2f m, %d stop signs) from %s; results to %s", track.name,
                      track.lap_length(), len(track.signs), node.key(keys.TRUTH), results.path or "nowhere")
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(judge_truth())
                tasks.create_task(publish_state())
        finally:
            if judge.lap is not None:  # the lap in progress, cut short
                results.write(lap_message(track.name, judge.lap, judge.now, clock.stamp))


if __name__ == "__main__":
    run(main)
