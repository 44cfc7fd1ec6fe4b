"""viz shows the lap judge (``judge/state``, ``judge/lap``): the lap time and penalty seconds as
scalars, the lap in words, each penalty once as a labelled marker where it happened (cleared when
a new lap starts) and a log line; a lap's result as a log line. Logged to a file, read back. <1 s."""

from __future__ import annotations

import numpy as np
import rerun as rr

from icefloe.schemas import messages as m
from icefloe.services.viz.logging_rr import RobotLogger
from icefloe.services.viz.readback import read_rrd

S = 1_000_000_000


def event(stamp: int, kind: str, lap: int, penalty: float, x: float, y: float, text: str) -> m.JudgeEvent:
    return m.JudgeEvent(stamp=stamp, kind=kind, lap=lap, penalty=penalty, x=x, y=y, text=text)  # type: ignore[arg-type]


def test_the_judge_in_rerun(tmp_path) -> None:
    out = tmp_path / "judge.rrd"
    rec = rr.RecordingStream("icefloe-test")
    rec.save(out)
    logger = RobotLogger(rec, "r1")
    start = event(1 * S, "lap_start", 1, 0.0, -0.6, -0.6, "lap 1 started")
    tyre = event(2 * S, "tyre_off", 1, 1.0, -0.5, -0.7, "right tyre off the road")
    bogged = event(3 * S, "bogged", 1, 5.0, -0.3, -0.85, "the whole robot off the road")
    logger.judge(m.JudgeState(stamp=2 * S, track="loop", lap=1, lap_time=1.0, penalties=1.0, tyre_off=1,
                              events=[start, tyre]))
    logger.judge(m.JudgeState(stamp=3 * S, track="loop", lap=1, lap_time=2.0, penalties=6.0, tyre_off=1, bogged=1,
                              events=[start, tyre, bogged]))
    logger.judge(m.JudgeState(stamp=4 * S, track="loop", lap=1, lap_time=3.0, penalties=6.0, tyre_off=1, bogged=1,
                              events=[start, tyre, bogged]))  # nothing new: no new marker, no new line
    logger.judge_lap(m.JudgeLap(stamp=5 * S, track="loop", lap=1, time=4.0, penalties=6.0, reward=0.0, score=10.0))
    logger.judge(m.JudgeState(stamp=5 * S, track="loop", lap=2, lap_time=0.0, penalties=0.0,
                              events=[start, tyre, bogged, event(5 * S, "lap_start", 2, 0.0, -0.6, -0.6, "")]))
    rec.flush()
    rec.disconnect()
    rows = read_rrd(out)
    marks = rows["/robots/r1/map/judge/penalties"]
    assert len(marks["stamp"]) == 3  # one new penalty, then another, then lap 2's empty map
    assert np.allclose(marks["Points2D:positions"][1], [[-0.5, -0.7], [-0.3, -0.85]])
    assert marks["Points2D:labels"][1] == ["+1 s tyre off", "+5 s bogged"]
    assert marks["Points2D:positions"][2] == []
    assert rows["/robots/r1/judge/lap_time"]["Scalars:scalars"] == [[1.0], [2.0], [3.0], [0.0]]
    assert rows["/robots/r1/judge/penalties"]["Scalars:scalars"] == [[1.0], [6.0], [6.0], [0.0]]
    lines = [row[0] for row in rows["/robots/r1/log/judge"]["TextLog:text"]]
    assert lines == ["lap 1: right tyre off the road (+1 s)", "lap 1: the whole robot off the road (+5 s)",
                     "lap 1 of loop: 4.00 s + 6 s - 0 s = 10.00 s"]
    text = rows["/robots/r1/judge/lap"]["TextDocument:text"]
    assert text[1] == ["loop: lap 1: 2.0 s, penalties 6 s (tyres 1, bogged 1, stop signs run 0)"]
