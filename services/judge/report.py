"""The judge's results as bus messages and as lines of the results file (no bus here)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import msgspec

from icefloe.errors import ConfigError
from icefloe.schemas import messages as m

from .scoring import Event, Judge, Lap

RECENT_EVENTS = 10
"""Events `JudgeState` carries."""


Stamper = Callable[[float], int]
"""A judge time (s) as ns since the epoch (`TruthTime.stamp`)."""


def ns(t: float) -> int:
    """Judge times that are epoch seconds already (truth timed by its stamps), as ns."""
    return round(t * 1e9)


def event_message(e: Event, stamp: Stamper = ns) -> m.JudgeEvent:
    return m.JudgeEvent(stamp=stamp(e.t), kind=e.kind, lap=e.lap, penalty=e.penalty, x=e.x, y=e.y,  # type: ignore[arg-type]
                        text=e.text)


def lap_message(track: str, lap: Lap, now: float, stamp: Stamper = ns) -> m.JudgeLap:
    end = lap.end if lap.end is not None else now
    return m.JudgeLap(stamp=stamp(end), track=track, lap=lap.number, time=lap.time(end), penalties=lap.penalties,
                      reward=lap.reward, score=lap.score(end), tyre_off=lap.tyre_off, bogged=lap.bogged,
                      ran_stop=lap.ran_stop, finished=lap.end is not None,
                      events=[event_message(e, stamp) for e in lap.events])


def state_message(judge: Judge, recent: list[Event], stamp: Stamper = ns) -> m.JudgeState:
    lap, done = judge.lap, judge.finished
    return m.JudgeState(
        stamp=stamp(judge.now), track=judge.track.name, lap=lap.number if lap else 0,
        lap_time=lap.time(judge.now) if lap else 0.0, penalties=lap.penalties if lap else 0.0,
        tyre_off=lap.tyre_off if lap else 0, bogged=lap.bogged if lap else 0, ran_stop=lap.ran_stop if lap else 0,
        laps=len(done), best_score=min((d.score(judge.now) for d in done), default=0.0),
        events=[event_message(e, stamp) for e in recent[-RECENT_EVENTS:]])


class Results:
    """The results file: one `JudgeLap` per line, appended (a judge restarted adds to it)."""

    def __init__(self, path: str, source: str = "") -> None:
        self.path = Path(path).expanduser() if path else None
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.path.touch()
            except OSError as exc:
                raise ConfigError(f"{source or 'config'}: judge.results: cannot write {self.path}: "
                                  f"{exc.strerror}") from None

    def write(self, lap: m.JudgeLap) -> None:
        if self.path is not None:
            with self.path.open("ab") as f:
                f.write(msgspec.json.encode(lap) + b"\n")


