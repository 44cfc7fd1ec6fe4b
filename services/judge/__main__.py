"""The lap judge: RVSS "Need 4 Speed"'s lap time, penalties and reward of a track world, from the truth.

    python -m icefloe.services.judge --config deploy/robots/sim.toml
    icefloe echo judge/state

It reads the simulator's truth (``sim/truth``) and the track of ``judge.world`` (else
``sim.world``), scores each lap by the workshop's rules (`scoring`, docs/judge.md), publishes
``judge/state`` (`JudgeState`) ``judge.rate_hz`` times a second and ``judge/lap`` (`JudgeLap`) at
each lap's end, logs each penalty as one line, and appends each lap to ``judge.results`` (JSON
lines), the lap in progress too when it stops. A world without a track is one line and exit
status 78 (`ConfigError`): `icefloe up` does not restart it.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import msgspec

from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.runtime import Node, run
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.worldmap import load_world

from .scoring import Event, Judge, Lap, Rules, TrackLike

RECENT_EVENTS = 10
"""Events `JudgeState` carries."""


def track_of(config: RobotConfig) -> TrackLike:
    """The judged world's track; `ConfigError` naming the world file when it has none."""
    name = config.judge.world or config.sim.world
    world = load_world(name)
    if world.track is None:
        raise ConfigError(f"{name}: track: the world has no track to judge (set `track = \"<layout>\"` in the "
                          "world file, or judge.world to a track world such as \"track\")")
    return world.track


def rules_of(config: RobotConfig) -> Rules:
    g, j = config.geometry, config.judge
    return Rules(wheel_track=g.track, wheel_diameter=g.wheel_diameter, radius=g.radius, stop_zone=j.stop_zone,
                 stop_dwell_s=j.stop_dwell_s, stop_tolerance=j.stop_tolerance)


def ns(t: float) -> int:
    return round(t * 1e9)


def event_message(e: Event) -> m.JudgeEvent:
    return m.JudgeEvent(stamp=ns(e.t), kind=e.kind, lap=e.lap, penalty=e.penalty, x=e.x, y=e.y,  # type: ignore[arg-type]
                        text=e.text)


def lap_message(track: str, lap: Lap, now: float) -> m.JudgeLap:
    end = lap.end if lap.end is not None else now
    return m.JudgeLap(stamp=ns(end), track=track, lap=lap.number, time=lap.time(end), penalties=lap.penalties,
                      reward=lap.reward, score=lap.score(end), tyre_off=lap.tyre_off, bogged=lap.bogged,
                      ran_stop=lap.ran_stop, finished=lap.end is not None,
                      events=[event_message(e) for e in lap.events])


def state_message(judge: Judge, recent: list[Event]) -> m.JudgeState:
    lap, done = judge.lap, judge.finished
    return m.JudgeState(
        stamp=ns(judge.now), track=judge.track.name, lap=lap.number if lap else 0,
        lap_time=lap.time(judge.now) if lap else 0.0, penalties=lap.penalties if lap else 0.0,
        tyre_off=lap.tyre_off if lap else 0, bogged=lap.bogged if lap else 0, ran_stop=lap.ran_stop if lap else 0,
        laps=len(done), best_score=min((d.score(judge.now) for d in done), default=0.0),
        events=[event_message(e) for e in recent[-RECENT_EVENTS:]])


class Results:
    """The results file: one `JudgeLap` per line, appended (a judge restarted adds to it)."""

    def __init__(self, path: str) -> None:
        self.path = Path(path).expanduser() if path else None
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.path.touch()
            except OSError as exc:
                raise ConfigError(f"judge.results: cannot write {self.path}: {exc.strerror}") from None

    def write(self, lap: m.JudgeLap) -> None:
        if self.path is not None:
            with self.path.open("ab") as f:
                f.write(msgspec.json.encode(lap) + b"\n")


async def main(config: RobotConfig) -> None:
    track = track_of(config)
    judge = Judge(track, rules_of(config))
    results = Results(config.judge.results)
    recent: list[Event] = []
    last_stamp = 0

    async with Node("judge", config) as node:
        state = node.publisher(keys.JUDGE_STATE)
        laps = node.publisher(keys.JUDGE_LAP)

        async def judge_truth() -> None:
            nonlocal last_stamp
            async for truth in node.subscribe(keys.TRUTH, latest=False):
                # (Non-finite numbers never get here: the subscription drops them with a line.)
                if truth.stamp <= last_stamp:  # an old sample (or another publisher's): time runs forward only
                    node.limited.warning("judge stamp", "sim/truth: stamp %d is not after the last one (%d); ignored",
                                         truth.stamp, last_stamp)
                    continue
                last_stamp = truth.stamp
                for event in judge.feed(truth.stamp / 1e9, truth.x, truth.y, truth.theta):
                    recent[:] = [*recent[-RECENT_EVENTS + 1:], event]
                    if event.penalty:
                        node.log.warning("lap %d: %s: +%.0f s at x %.2f m, y %.2f m", event.lap, event.text,
                                         event.penalty, event.x, event.y)
                    else:
                        node.log.info("%s", event.text)
                    if event.kind == "lap_end":
                        done = judge.finished[-1]
                        message = lap_message(track.name, done, judge.now)
                        laps.put(message)
                        results.write(message)

        async def publish_state() -> None:
            period = 1.0 / config.judge.rate_hz
            while True:
                state.put(state_message(judge, recent))
                await asyncio.sleep(period)

        node.log.info("judging track %s (lap %.2f m, %d stop signs) from %s; results to %s", track.name,
                      track.lap_length(), len(track.signs), node.key(keys.TRUTH), results.path or "nowhere")
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(judge_truth())
                tasks.create_task(publish_state())
        finally:
            if judge.lap is not None:  # the lap in progress, cut short
                results.write(lap_message(track.name, judge.lap, judge.now))


if __name__ == "__main__":
    run(main)
