"""``icefloe score`` as a process: on the example files, on hostile ones, and on a real robot's bus
and a recording of it made by ``icefloe record``.

The file tests take about a second each (a process each); the robot test about 20 s (the simulated
robot, odometry, the recorder and three scoring processes).
"""

from __future__ import annotations

import asyncio
import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest
from conftest import ROOT, Robot, wait_for
from test_bag_cli import cli, icefloe

from icefloe.schemas import codec, keys
from icefloe.schemas import messages as m
from icefloe.worldmap import load_world

ICEFLOE = [sys.executable, "-m", "icefloe.cli"]
EXAMPLES = "examples/score"
LAB = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}


def run(*args: str) -> tuple[int, str, str]:
    done = subprocess.run([*ICEFLOE, *args], cwd=ROOT, capture_output=True, text=True, timeout=120)
    return done.returncode, done.stdout, done.stderr


@pytest.fixture
def main(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch):
    """``icefloe`` in this process (what a process runs, but for the interpreter's start): for the many
    hostile inputs, each a second faster than a process on a busy machine."""
    from icefloe.cli import main as icefloe_main

    monkeypatch.chdir(ROOT)

    def call(*args: str) -> tuple[int, str, str]:
        try:
            status = icefloe_main(list(args))
        except SystemExit as exc:  # argparse
            status = int(exc.code or 0)
        out, err = capsys.readouterr()
        return status, out, err

    return call


def test_score_map_prints_the_rmse_each_marker_and_the_missed_and_spurious_ones() -> None:
    status, out, err = run("score", "map", f"{EXAMPLES}/slam.txt", "--world", f"{EXAMPLES}/true_map.txt")
    assert status == 0, err
    assert "RMSE:      0.040 m after alignment (0.510 m before)" in out  # as ECE4078's SLAM_eval prints it
    assert "alignment: rigid: rotation +10.30 deg" in out
    assert "missed:    10, 11 (in the world, not in the map)" in out
    assert "spurious:  42 (in the map, not in the world)" in out
    assert "\n   5    0.067        1.223        2.063      1.200     2.000\n" in out


@pytest.mark.timeout(300)
def test_score_map_json_for_scripts_and_the_other_alignments(main) -> None:
    status, out, err = run("score", "map", f"{EXAMPLES}/map.json", "--world", "lab", "--json")
    assert status == 0, err
    result = json.loads(out)
    assert result["rmse"] == pytest.approx(0.03989498264098227, rel=1e-12)
    assert result["missed"] == [10, 11] and result["spurious"] == [42] and result["matched"] == 10
    assert set(result["markers"]) == {str(i) for i in range(10)}
    assert result["alignment"]["kind"] == "rigid" and result["alignment"]["scale"] == 1.0
    similar = json.loads(main("score", "map", f"{EXAMPLES}/map.json", "--world", "lab", "--json",
                             "--align", "similarity")[1])
    assert similar["rmse"] <= result["rmse"] and similar["alignment"]["scale"] != 1.0
    raw = json.loads(main("score", "map", f"{EXAMPLES}/map.json", "--world", "lab", "--json", "--align", "none")[1])
    assert raw["rmse"] == pytest.approx(result["rmse_before"])


@pytest.mark.timeout(300)  # two processes: slow to start on a busy machine
def test_score_path_prints_ate_and_rpe() -> None:
    status, out, err = run("score", "path", f"{EXAMPLES}/odom.csv", "--truth", f"{EXAMPLES}/truth.csv")
    assert status == 0, err
    assert "associated: 263 poses, each within 0.02 s of a true pose (0 without one)" in out
    assert "ATE:        RMSE 0.030 m" in out and "RPE:        2.43 % of distance travelled, 1.570 deg/m" in out
    status, out, err = run("score", "path", f"{EXAMPLES}/odom.csv", "--truth", f"{EXAMPLES}/truth.csv",
                           "--json", "--segment", "10")
    result = json.loads(out)
    assert result["rpe"]["segments"] == 0 and result["rpe"]["translation_pct"] is None
    assert result["ate"]["rmse"] == pytest.approx(0.030, abs=5e-4)


@pytest.mark.parametrize(("content", "args", "error"), [
    ('{"taglist": [1, 2], "map": [[0, 1], [0', (), "{path}: not valid JSON"),
    ('{"landmarks": []}', (), "{path}: the map is empty: nothing to score"),
    ('{"landmarks": [{"id": 2, "x": 2.0, "y": 1.2}]}', (),
     "{path}: 1 of its 1 markers are in world lab: rigid alignment needs at least 2 matched points, got 1"),
    ('{"landmarks": [{"id": 2, "x": 2.0, "y": 1.2}, {"id": 3, "x": 0, "y": 2}]}', ("--align", "similarity"),
     "similarity alignment needs at least 3 matched points, got 2"),
    ('{"taglist": [1], "map": [[NaN], [0]]}', (), "{path}: marker 1 is at (nan, 0.0): not a finite position"),
])
def test_a_bad_map_is_one_line_naming_the_file(main, tmp_path: Path, content: str, args: tuple[str, ...],
                                               error: str) -> None:
    path = tmp_path / "slam.txt"
    path.write_text(content)
    status, out, err = main("score", "map", str(path), "--world", "lab", *args)
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("icefloe: ") and error.format(path=path) in err, err


def test_missing_files_and_trajectories_that_do_not_meet_are_one_line_each(main, tmp_path: Path) -> None:
    status, out, err = run("score", "map", "nothere.txt", "--world", "lab")  # as a process, once
    assert status == 2 and out == "" and err == "icefloe: nothere.txt: No such file or directory\n"
    status, _, err = main("score", "map", f"{EXAMPLES}/slam.txt", "--world", "nowhere")
    assert status == 2 and err.count("\n") == 1 and "nowhere" in err
    late = tmp_path / "late.csv"
    late.write_text("t,x,y,theta\n100,0,0,0\n101,1,0,0\n")
    status, _, err = main("score", "path", str(late), "--truth", f"{EXAMPLES}/truth.csv")
    assert status == 2 and err.count("\n") == 1, err
    assert f"{late} against {EXAMPLES}/truth.csv: 0 poses are within 0.02 s of a true pose" in err
    status, _, err = main("score", "path", str(late), "--truth", f"{EXAMPLES}/truth.csv", "--max-dt", "nan")
    assert status == 2 and "--max-dt: must be a positive number" in err
    # A wildcard would read every robot's maps or poses as one: refused before any session opens.
    status, _, err = main("score", "map", "icefloe/*/slam/map", "--world", "lab")
    assert (status, err) == (2, "icefloe: icefloe/*/slam/map: one map is read from one key, not a wildcard\n")
    status, _, err = main("score", "path", "loc/pose", "--truth", "icefloe/**", "--robot", "x")
    assert (status, err) == (2, "icefloe: icefloe/**: a trajectory is read from one key, not a wildcard\n")


# --------------------------------------------------------------------------- a real robot, live and recorded


def icefloe_map(moved: dict[int, tuple[float, float]]) -> bytes:
    return msgspec.json.encode({"stamp": 0, "landmarks": [{"id": i, "x": x, "y": y} for i, (x, y) in moved.items()]})


async def publish_map(node, key: str, payload: bytes) -> None:
    while True:
        node.session.put(key, payload, encoding=codec.JSON)
        await asyncio.sleep(0.2)


@pytest.mark.slow
@pytest.mark.timeout(400)  # about 20 s alone; a loaded machine starts processes many times slower
async def test_scores_of_a_live_robot_and_of_its_recording(robot: Robot) -> None:
    """The simulated robot drives; odometry is scored against sim/truth live (ended with Ctrl-C) and
    from a recording of both by ``icefloe record``, a bad sample on sim/truth skipped by both; a map
    published on a key outside the key table
    (marker 1 moved 5 cm outwards: RMSE 0.05 sqrt(11) / 12 after a rigid alignment, see test_score.py)
    is scored live (one sample) and from the recording (its last map)."""
    expected = 0.05 * math.sqrt(11) / 12
    est = dict(LAB)
    est[1] = (2.05, 0.0)
    out = robot.tmp / "run.mcap"
    config = ("--config", str(robot.config_path))
    map_key = f"icefloe/{robot.name}/slam/map"
    recorder = cli(robot, "record", "-o", str(out), "--nice", "0", "odom/pose", "sim/truth", "slam/map", name="record")
    services = [robot.start(s) for s in ("sim", "hwbridge", "odometry")]
    async with robot.node("tester") as node:
        poses: list[m.Pose] = []
        listening = asyncio.create_task(_collect(node.subscribe(keys.ODOM_POSE, latest=False), poses))
        await wait_for(lambda: poses and "recording" in recorder.output, timeout=120)
        live = cli(robot, "score", "path", "odom/pose", "--truth", "sim/truth", "--duration", "60",
                   "--segment", "0.2", "--json", name="live-path")
        await wait_for(lambda: "collecting" in live.output, timeout=120)
        publishing = asyncio.create_task(publish_map(node, map_key, icefloe_map(est)))
        status, text, err = await icefloe("score", "map", "slam/map", "--world", "lab", "--json", "--timeout", "60",
                                          *config, timeout=120)
        assert status == 0, err
        live_map = json.loads(text)
        twist = node.publisher(keys.TWIST)
        node.session.put(f"icefloe/{robot.name}/sim/truth", b"\xc1 not a pose", encoding=codec.MSGPACK)  # hostile
        for v, w, seconds in ((0.25, 0.0, 2.0), (0.15, 1.0, 1.5)):
            for _ in range(round(seconds / 0.05)):
                twist.put(m.Twist(v=v, w=w))
                await asyncio.sleep(0.05)
        node.publisher(keys.STOP).put(m.Stop())
        await asyncio.sleep(0.5)
        live.signal(signal.SIGINT)  # Ctrl-C: score what came so far
        assert await asyncio.to_thread(live.popen.wait, 120) == 0, live.output
        assert recorder.stop(signal.SIGINT) == 0, recorder.output
        publishing.cancel()
        listening.cancel()
    for proc in services:
        assert proc.alive(), proc.output

    assert live_map["rmse"] == pytest.approx(expected, rel=1e-9) and live_map["map"] == f"{map_key} (one sample)"
    live_path = json.loads(next(line for line in live.output.splitlines() if line.startswith("{")))
    status, text, err = await icefloe("score", "path", str(out), "--key", "odom/pose", "--truth", str(out),
                                      "--segment", "0.2", "--json", timeout=120)
    assert status == 0, err
    recorded_path = json.loads(text)
    # The bad sample: skipped with one line, live and recorded.
    assert "sim/truth: a sample does not decode" in live.output and "(skipped)" in live.output
    assert err.count("\n") == 1 and "sim/truth: a message does not decode" in err and "(1 message skipped)" in err
    status, text, err = await icefloe("score", "map", str(out), "--world", "lab", "--json", timeout=120)
    assert status == 0, err
    recorded_map = json.loads(text)
    print(f"\nlive: {live_path}\nrecorded: {recorded_path}")

    assert recorded_map["rmse"] == pytest.approx(expected, rel=1e-9) and map_key in recorded_map["map"]
    for result in (live_path, recorded_path):
        assert result["pairs"] > 50, result  # 3.5 s of driving at 50 Hz, and the standing before and after
        assert result["rpe"]["distance"] > 0.5 and result["rpe"]["segments"] > 10
        assert result["ate"]["rmse"] < 0.02  # odometry of a robot that does not slip, over a metre
    # Live and recorded see the same samples, but for the few around the Ctrl-C and the start.
    assert recorded_path["ate"]["rmse"] == pytest.approx(live_path["ate"]["rmse"], abs=0.005)


async def _collect(sub, into: list) -> None:
    async for item in sub:
        into.append(item)
