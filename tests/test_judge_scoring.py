"""The lap judge's rules (services/judge/scoring.py) on scripted truth, over a small fake track.

The fake track is shaped like the shipped one: a closed loop of road (a 2 m x 1.2 m rectangle of
centerline, 0.3 m wide), the start/finish line on its bottom side, driven counter-clockwise, and
one stop sign on its right side, its face looking at the traffic (which drives +y there). Truth
samples come at 50 Hz, as the simulator's (``sim.truth_rate_hz``), at 0.2 m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from icefloe.services.judge.scoring import (
    BOGGED_PENALTY,
    SAFE_REWARD,
    STOP_PENALTY,
    TYRE_PENALTY,
    Judge,
    Rules,
)

RATE_HZ = 50.0
SPEED = 0.2
WIDTH = 0.3
CORNERS = np.array([[-1.0, -0.6], [1.0, -0.6], [1.0, 0.6], [-1.0, 0.6], [-1.0, -0.6]])
START = (0.0, -0.6, 0.0)
STOP_LINE = (1.0, 0.0)


@dataclass(frozen=True)
class FakeSign:
    kind: str = "stop"
    x: float = 1.25
    y: float = 0.05
    yaw: float = -math.pi / 2  # looks at traffic coming up the right side (driving +y)
    size: float = 0.1
    stop_x: float = STOP_LINE[0]
    stop_y: float = STOP_LINE[1]


@dataclass(frozen=True)
class FakeTrack:
    """A rectangle of road; its centerline from the start line round, closed."""

    name: str = "fake"
    road_width: float = WIDTH
    signs: tuple[FakeSign, ...] = (FakeSign(),)
    start: tuple[float, float, float] = START
    line: np.ndarray = field(default_factory=lambda: np.vstack([[START[:2]], CORNERS[1:], [START[:2]]]))

    def on_road(self, x: float, y: float) -> bool:
        return _distance(self.line, x, y) <= self.road_width / 2

    def centerline(self) -> np.ndarray:
        return self.line

    def lap_length(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.line, axis=0).T)))


def _distance(line: np.ndarray, x: float, y: float) -> float:
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(((x - a[:, 0]) * ab[:, 0] + (y - a[:, 1]) * ab[:, 1]) / (ab ** 2).sum(axis=1), 0, 1)
    return float(np.min(np.hypot(a[:, 0] + t * ab[:, 0] - x, a[:, 1] + t * ab[:, 1] - y)))


class Script:
    """Truth samples, made by driving between points at `SPEED` and standing still."""

    def __init__(self, x: float, y: float, theta: float = 0.0) -> None:
        self.t, self.x, self.y, self.theta = 0.0, x, y, theta
        self.samples = [(0.0, x, y, theta)]

    def to(self, x: float, y: float, speed: float = SPEED) -> Script:
        dist = math.hypot(x - self.x, y - self.y)
        heading = math.atan2(y - self.y, x - self.x)
        steps = max(1, math.ceil(dist / speed * RATE_HZ))
        x0, y0 = self.x, self.y
        for k in range(1, steps + 1):
            self.t += dist / speed / steps
            self.samples.append((self.t, x0 + (x - x0) * k / steps, y0 + (y - y0) * k / steps, heading))
        self.x, self.y, self.theta = x, y, heading
        return self

    def lap(self, stop_before: float | None = 0.05, extra: float = 0.2) -> Script:
        """Round the loop from here (just behind the start line) to ``extra`` past it; stop with the
        front ``stop_before`` m before the stop line (None: do not stop)."""
        self.to(1.0, -0.6)
        if stop_before is not None:
            self.to(1.0, STOP_LINE[1] - Rules().radius - stop_before).wait(1.0)
        for cx, cy in CORNERS[2:]:
            self.to(cx, cy)
        return self.to(START[0] + extra, START[1])

    def wait(self, seconds: float) -> Script:
        for _ in range(round(seconds * RATE_HZ)):
            self.t += 1 / RATE_HZ
            self.samples.append((self.t, self.x, self.y, self.theta))
        return self


def judged(script: Script, track: FakeTrack | None = None) -> tuple[Judge, list]:
    judge = Judge(track or FakeTrack())
    events = [e for sample in script.samples for e in judge.feed(*sample)]
    return judge, events


def kinds(events: list) -> list[str]:
    return [e.kind for e in events]


def test_a_clean_lap_with_a_stop_is_timed_and_rewarded():
    judge, events = judged(Script(-0.1, -0.6).lap(stop_before=0.05))
    assert kinds(events) == ["lap_start", "stopped", "lap_end", "lap_start"]
    lap = judge.finished[0]
    expected = FakeTrack().lap_length() / SPEED + 1.0  # the loop at 0.2 m/s and the 1 s stop
    assert lap.time(judge.now) == pytest.approx(expected, abs=2 / RATE_HZ)
    assert (lap.penalties, lap.reward) == (0.0, SAFE_REWARD)
    assert lap.score(judge.now) == pytest.approx(expected - SAFE_REWARD, abs=2 / RATE_HZ)
    assert judge.lap is not None and judge.lap.number == 2  # the next lap runs from the same crossing


def test_one_tyre_off_then_the_whole_robot_off():
    rules = Rules()
    # Along the bottom side: right tyre (y - track/2) wholly below the road's edge, centre still on it.
    one_tyre = START[1] - (WIDTH / 2 + rules.wheel_track / 2 - 0.03)
    bogged = START[1] - (WIDTH / 2 + rules.radius + 0.05)
    script = Script(-0.1, -0.6).to(0.2, -0.6).to(0.3, one_tyre).to(0.4, -0.6)  # out and back: +1
    script.to(0.5, bogged).to(0.6, bogged).to(0.7, -0.6)  # both tyres (+1 +1), then all of it (+5)
    script.to(1.0, -0.6).lap(stop_before=0.05)
    judge, events = judged(script)
    penalties = [(e.kind, e.text, e.penalty) for e in events if e.penalty]
    assert penalties == [
        ("tyre_off", "right tyre off the road", TYRE_PENALTY),
        ("tyre_off", "right tyre off the road", TYRE_PENALTY),
        ("tyre_off", "left tyre off the road", TYRE_PENALTY),
        ("bogged", "the whole robot off the road", BOGGED_PENALTY),
    ]
    lap = judge.finished[0]
    assert (lap.tyre_off, lap.bogged, lap.ran_stop) == (3, 1, 0)
    assert lap.penalties == 3 * TYRE_PENALTY + BOGGED_PENALTY and lap.reward == 0.0
    assert lap.score(judge.now) == pytest.approx(lap.time(judge.now) + 8.0)


def test_running_a_stop_sign_costs_ten_seconds():
    judge, events = judged(Script(-0.1, -0.6).lap(stop_before=None))
    assert [(e.kind, e.penalty) for e in events if e.penalty] == [("ran_stop", STOP_PENALTY)]
    lap = judge.finished[0]
    assert (lap.ran_stop, lap.penalties, lap.reward) == (1, STOP_PENALTY, 0.0)
    assert lap.events[1].x == pytest.approx(STOP_LINE[0]) and abs(lap.events[1].y - STOP_LINE[1]) < SPEED / RATE_HZ


def test_a_stop_5_cm_before_the_line_counts():
    judge, events = judged(Script(-0.1, -0.6).lap(stop_before=0.05))
    stopped = [e for e in events if e.kind == "stopped"]
    assert len(stopped) == 1 and "5 cm" in stopped[0].text
    assert judge.finished[0].ran_stop == 0


def test_a_stop_20_cm_before_the_line_does_not():
    judge, events = judged(Script(-0.1, -0.6).lap(stop_before=0.20))
    assert "stopped" not in kinds(events)
    assert judge.finished[0].ran_stop == 1 and judge.finished[0].penalties == STOP_PENALTY


def test_a_pause_shorter_than_the_dwell_is_not_a_stop():
    script = Script(-0.1, -0.6).to(1.0, -0.6).to(1.0, -0.15).wait(0.3)  # front 5 cm before, 0.3 s only
    script.to(1.0, 0.6).to(-1.0, 0.6).to(-1.0, -0.6).to(0.2, -0.6)
    judge, _ = judged(script)
    assert judge.finished[0].ran_stop == 1


def test_a_stop_past_the_line_does_not_count():
    # The centre 5 cm before the line: the front (radius 0.1 m ahead) is already over it.
    script = Script(-0.1, -0.6).to(1.0, -0.6).to(1.0, -0.05).wait(1.0)
    script.to(1.0, 0.6).to(-1.0, 0.6).to(-1.0, -0.6).to(0.2, -0.6)
    judge, _ = judged(script)
    assert judge.finished[0].ran_stop == 1


def test_the_other_way_past_the_sign_is_not_running_it():
    # Down the right side (-y): the sign stops traffic going up, not this.
    script = Script(-0.1, -0.6).to(0.5, -0.6).to(1.0, -0.6).to(1.0, 0.6).to(1.0, -0.3)
    _, events = judged(script)
    assert [e.kind for e in events if e.kind == "ran_stop"] == ["ran_stop"]  # once, going up


def test_back_and_forth_over_the_start_line_is_not_a_lap():
    script = Script(-0.1, -0.6).to(0.1, -0.6).to(-0.1, -0.6).to(0.1, -0.6)
    judge, events = judged(script)
    assert kinds(events) == ["lap_start"] and judge.finished == []


def test_penalties_before_the_first_lap_do_not_count():
    script = Script(-0.5, -0.6).to(-0.4, -1.0).to(-0.3, -0.6).to(-0.1, -0.6).to(0.1, -0.6)
    judge, events = judged(script)
    early = [e for e in events if e.kind in ("tyre_off", "bogged")]
    assert early and all(e.lap == 0 and e.penalty == 0 for e in early)
    assert judge.lap is not None and judge.lap.penalties == 0


def test_the_lap_starts_at_the_interpolated_crossing():
    # Samples at x = -0.004 and +0.000 (on the line: not yet over), then +0.004: crossed between.
    judge = Judge(FakeTrack())
    judge.feed(0.00, -0.004, -0.6, 0.0)
    judge.feed(0.02, 0.000, -0.6, 0.0)
    assert judge.lap is None
    judge.feed(0.04, 0.004, -0.6, 0.0)
    assert judge.lap is not None and judge.lap.start == pytest.approx(0.02)


def test_a_lap_of_the_shipped_track():
    """The real track (deploy/worlds/track.toml): round its centerline at 0.2 m/s from 10 cm behind
    the start line to 10 cm past it, stopping for 1 s with the front 5 cm before the stop line."""
    from icefloe.worldmap import load_world

    track = load_world("track").track
    assert track is not None
    line = track.centerline()
    sign = track.signs[0]
    stop_at = int(np.argmin(np.hypot(*(line - [sign.stop_x, sign.stop_y]).T)))
    x0, y0, yaw = track.start
    script = Script(x0 - 0.1 * math.cos(yaw), y0 - 0.1 * math.sin(yaw), yaw)
    before = Rules().radius + 0.05  # the centre this far before the line puts the front 5 cm before it
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
    stop_point = np.array([np.interp(arc[stop_at] - before, arc, line[:, k]) for k in (0, 1)])
    stop_arc = arc[stop_at] - before
    for i, (x, y) in enumerate(line[1:], start=1):
        if arc[i - 1] < stop_arc <= arc[i]:
            script.to(*stop_point).wait(1.0)
        script.to(x, y)
    script.to(x0 + 0.1 * math.cos(yaw), y0 + 0.1 * math.sin(yaw))
    judge, events = judged(script, track)  # type: ignore[arg-type]
    assert kinds(events) == ["lap_start", "stopped", "lap_end", "lap_start"], [e.text for e in events]
    lap = judge.finished[0]
    expected = track.lap_length() / SPEED + 1.0
    assert lap.time(judge.now) == pytest.approx(expected, abs=0.1)
    assert lap.score(judge.now) == pytest.approx(expected - SAFE_REWARD, abs=0.1)


def test_the_results_as_messages_and_file_lines(tmp_path):
    import msgspec

    from icefloe.schemas import codec
    from icefloe.schemas import messages as m
    from icefloe.services.judge.report import Results, lap_message, state_message

    judge, events = judged(Script(-0.1, -0.6).lap(stop_before=None))
    done = lap_message("fake", judge.finished[0], judge.now)
    assert (done.lap, done.finished, done.ran_stop, done.penalties, done.reward) == (1, True, 1, STOP_PENALTY, 0.0)
    assert done.score == pytest.approx(done.time + STOP_PENALTY)
    assert [e.kind for e in done.events] == ["lap_start", "ran_stop", "lap_end"]
    assert codec.decode(codec.encode(done), codec.MSGPACK, m.JudgeLap) == done  # what the bus carries
    state = state_message(judge, events)
    assert (state.lap, state.laps, state.best_score, state.penalties) == (2, 1, done.score, 0.0)
    assert len(state.events) == len(events) and state.events[-1].kind == "lap_start"
    results = Results(str(tmp_path / "sub" / "results.jsonl"))
    results.write(done)
    results.write(lap_message("fake", judge.laps[-1], judge.now))
    lines = [msgspec.json.decode(line, type=m.JudgeLap) for line in results.path.read_bytes().splitlines()]
    assert lines[0] == done and lines[1].finished is False and lines[1].lap == 2


def test_an_unwritable_results_file_names_the_setting(tmp_path):
    from icefloe.errors import ConfigError
    from icefloe.services.judge.report import Results

    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match=r"^robot.toml: judge.results: cannot write"):
        Results(str(tmp_path / "file" / "results.jsonl"), "robot.toml")


def test_the_judge_times_by_the_simulators_clock():
    from icefloe.schemas import messages as m
    from icefloe.services.judge.timing import TruthTime

    def truth(stamp_s: float, sim_time: float = 0.0) -> m.Truth:
        return m.Truth(stamp=round(stamp_s * 1e9), x=0.0, y=0.0, theta=0.0, sim_time=sim_time)

    clock = TruthTime()
    assert clock.seconds(truth(1000.0)) == 1000.0  # no sim_time yet: the stamps
    assert clock.stamp(1000.0) == 1000 * 10**9
    # The simulator's clock from now on, carrying on where the stamps were (no jump back).
    assert clock.seconds(truth(1000.5, sim_time=20.0)) == pytest.approx(1000.0)
    # A busy machine: 1 s of wall time, 0.6 s simulated (steps dropped): the judge takes 0.6 s.
    assert clock.seconds(truth(1001.5, sim_time=20.6)) == pytest.approx(1000.6)
    assert clock.stamp(1000.6) == 1001_500_000_000  # and stamps events with the wall clock
    # Once sim_time came, a sample without it is refused (it would jump by decades).
    assert clock.seconds(truth(1001.6)) is None
    # The simulator started again: its clock went back to 0.02 s; the judge's carries on.
    assert clock.seconds(truth(1003.0, sim_time=0.02)) == pytest.approx(1000.6)
    assert clock.seconds(truth(1003.1, sim_time=0.12)) == pytest.approx(1000.7)


def test_the_shortcut_across_the_shipped_track_is_no_lap():
    """Through the middle (the road between its two T junctions) and back to the start line: the
    lap's second quarter (the right-hand side) was never driven, so crossing the line ends nothing."""
    from icefloe.worldmap import load_world

    track = load_world("track").track
    assert track is not None
    script = Script(-0.7, -0.6).to(0.0, -0.6).to(0.0, 0.6).to(-1.2, 0.6).to(-1.2, -0.6).to(-0.5, -0.6)
    judge, events = judged(script, track)  # type: ignore[arg-type]
    assert [e.kind for e in events if e.kind.startswith("lap")] == ["lap_start"] and judge.finished == []
