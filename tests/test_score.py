"""Scoring maths and readers (icefloe/score), on hand-made maps and trajectories whose scores are known.

No processes: a second or two. The CLI as a process, and recordings made by the suite's tools, are
in test_score_cli.py.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import numpy as np
import pytest
from conftest import ROOT

from icefloe.bag import BagWriter
from icefloe.errors import BadRecording
from icefloe.schemas import codec
from icefloe.schemas import messages as m
from icefloe.score import inputs
from icefloe.score.maths import Alignment, NotEnough, Trajectory, align, associate, score_map, score_path
from icefloe.worldmap import load_world

EXAMPLES = ROOT / "examples" / "score"
LAB = {mk.id: (mk.x, mk.y) for mk in load_world("lab").markers}


def moved(points: dict[int, tuple[float, float]], a: Alignment) -> dict[int, tuple[float, float]]:
    ids = list(points)
    out = a.apply(np.array([points[i] for i in ids]))
    return {i: (float(p[0]), float(p[1])) for i, p in zip(ids, out, strict=True)}


# --------------------------------------------------------------------------- maps


@pytest.mark.parametrize("kind", ["rigid", "similarity"])
def test_a_map_moved_exactly_scores_zero_after_alignment(kind: str) -> None:
    frame = Alignment(rotation=2.3, translation=(0.7, -1.9), scale=1.0 if kind == "rigid" else 0.8)
    score = score_map(moved(LAB, frame), LAB, kind)
    assert score.rmse < 1e-12 and max(score.errors.values()) < 1e-12
    assert score.rmse_raw > 1.0  # before alignment it is far off
    # The alignment found is the inverse of the move.
    assert score.alignment.rotation == pytest.approx(-2.3)
    assert score.alignment.scale == pytest.approx(1 / frame.scale)
    assert score.missed == [] and score.spurious == []


def test_a_scaled_map_is_not_zero_under_rigid_alignment() -> None:
    score = score_map(moved(LAB, Alignment(scale=1.1)), LAB, "rigid")
    assert score.rmse > 0.1


def test_one_marker_off_by_5_cm_gives_the_rmse_worked_out_by_hand() -> None:
    """Marker 1 (2, 0) moved 5 cm away from the room's centre (the markers' centroid, the origin): the
    best rigid alignment keeps the rotation (the move has no moment about the centroid) and shifts
    everything by e/N, so the moved marker is off by e(N-1)/N, the others by e/N, and
    RMSE = e sqrt(N-1) / N. Without alignment: e / sqrt(N)."""
    est = dict(LAB)
    est[1] = (2.05, 0.0)
    n, e = len(LAB), 0.05
    score = score_map(est, LAB, "rigid")
    assert score.rmse == pytest.approx(e * math.sqrt(n - 1) / n, rel=1e-9)  # 0.01382 m
    assert score.errors[1] == pytest.approx(e * (n - 1) / n, rel=1e-9)
    assert all(score.errors[i] == pytest.approx(e / n, rel=1e-9) for i in LAB if i != 1)
    assert score.alignment.rotation == pytest.approx(0.0, abs=1e-12)
    assert score_map(est, LAB, "none").rmse == pytest.approx(e / math.sqrt(n), rel=1e-12)


def test_missed_and_spurious_markers_are_listed_and_left_out_of_the_rmse() -> None:
    est = {i: p for i, p in LAB.items() if i not in (3, 7)}
    est[42] = (9.0, 9.0)  # far away: were it counted, the RMSE would show it
    score = score_map(est, LAB)
    assert score.missed == [3, 7] and score.spurious == [42]
    assert score.rmse < 1e-12 and sorted(score.errors) == sorted(set(LAB) - {3, 7})


def test_alignment_needs_enough_markers_and_says_so() -> None:
    one = {0: LAB[0]}
    with pytest.raises(NotEnough, match="rigid alignment needs at least 2 matched points, got 1"):
        score_map(one, LAB, "rigid")
    two = {0: LAB[0], 1: LAB[1]}
    assert score_map(two, LAB, "rigid").rmse < 1e-12
    with pytest.raises(NotEnough, match="similarity alignment needs at least 3"):
        score_map(two, LAB, "similarity")
    assert score_map(one, LAB, "none").rmse == 0.0
    with pytest.raises(NotEnough, match="all at one place"):
        align(np.zeros((3, 2)), np.ones((3, 2)))
    with pytest.raises(NotEnough, match="got 0"):
        score_map({99: (0.0, 0.0)}, LAB)


def test_a_mirrored_map_is_aligned_by_a_rotation_never_a_reflection() -> None:
    mirrored = {i: (x, -y) for i, (x, y) in LAB.items()}
    a = align(np.array(list(mirrored.values())), np.array(list(LAB.values())))
    r = np.array([[math.cos(a.rotation), -math.sin(a.rotation)], [math.sin(a.rotation), math.cos(a.rotation)]])
    assert np.linalg.det(r) == pytest.approx(1.0)
    assert score_map(mirrored, LAB).rmse > 0.5


def test_the_ece4078_example_scores_as_the_course_s_slam_eval_does() -> None:
    """examples/score: a map in ECE4078's slam.txt format against ECE4078's true map of the lab. The
    course's SLAM_eval.py (its Umeyama, apply_transform and compute_slam_rmse), run on these two
    files, printed RMSE 0.03989498264098227 after alignment and 0.5103251336158156 before; so must we."""
    est, _ = inputs.read_map(str(EXAMPLES / "slam.txt"))
    truth, _ = inputs.true_map(str(EXAMPLES / "true_map.txt"))
    score = score_map(est, truth, "rigid")
    assert score.rmse == pytest.approx(0.03989498264098227, rel=1e-12)
    assert score.rmse_raw == pytest.approx(0.5103251336158156, rel=1e-12)
    assert score.missed == [10, 11] and score.spurious == [42]
    assert truth == LAB  # the true map and the lab world are the same markers
    # icefloe's own format holds the same map, and scores the same.
    own, _ = inputs.read_map(str(EXAMPLES / "map.json"))
    assert own == est


# --------------------------------------------------------------------------- map files, hostile


def write(tmp_path: Path, name: str, content: bytes | str) -> str:
    path = tmp_path / name
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    return str(path)


@pytest.mark.parametrize(("content", "error"), [
    ('{"taglist": [1, 2', "not valid JSON"),
    ("", "neither JSON nor MessagePack"),
    (b"\xc1\xc1\xc1", "neither JSON nor MessagePack"),
    ('{"taglist": [1, 2], "map": [[0, 1], [0, 1], [0, 1]]}', "`map` must be 2 x 2"),
    ('{"taglist": [1, 2, 3], "map": [[0, 1], [0, 1], [2, 2]]}', "`map` must be 2 x 3"),
    ('{"taglist": ["a"], "map": [[0], [0]]}', "Expected `int`, got `str` - at `$.taglist[0]`"),
    ('{"taglist": [1, 1], "map": [[0, 1], [0, 1]]}', "marker 1 appears twice"),
    ('{"landmarks": [{"id": 1, "x": "near", "y": 0}]}', "Expected `float`, got `str`"),
    ('{"landmarks": [{"id": -1, "x": 0, "y": 0}]}', "Expected `int` >= 0"),
    ('{"landmarks": [{"id": 1, "x": 1e999, "y": 0}]}', "marker 1 is at (inf, 0.0): not a finite position"),
    ('{"taglist": [5], "map": [[NaN], [0.5]]}', "marker 5 is at (nan, 0.5): not a finite position"),
    ('{"markers": []}', "not a landmark map (a map with keys markers)"),
    ("[1, 2, 3]", "not a landmark map (list)"),
])
def test_a_bad_map_file_is_one_error_naming_the_file(tmp_path: Path, content: str | bytes, error: str) -> None:
    path = write(tmp_path, "bad.txt", content)
    with pytest.raises(inputs.BadInput) as exc:
        inputs.read_map(path)
    assert str(exc.value).startswith(path) and error in str(exc.value), exc.value
    assert "\n" not in str(exc.value)


def test_nan_in_a_messagepack_map_is_refused(tmp_path: Path) -> None:
    path = write(tmp_path, "map.msgpack", msgspec.msgpack.encode({"landmarks": [{"id": 4, "x": math.nan, "y": 0.0}]}))
    with pytest.raises(inputs.BadInput, match=r"marker 4 is at \(nan, 0.0\): not a finite position"):
        inputs.read_map(path)


def test_an_empty_map_reads_as_empty_and_a_missing_file_names_itself(tmp_path: Path) -> None:
    assert inputs.read_map(write(tmp_path, "empty.json", '{"landmarks": []}'))[0] == {}
    with pytest.raises(inputs.BadInput, match=r"nothere.json: No such file"):
        inputs.read_map(str(tmp_path / "nothere.json"))
    with pytest.raises(inputs.BadInput, match="Is a directory"):
        inputs.read_map(str(tmp_path))


def test_true_maps_bad_ones_and_a_world_that_does_not_exist(tmp_path: Path) -> None:
    assert inputs.true_map("lab")[0] == LAB
    world = tmp_path / "mine.toml"  # a world file is a map too (the localizer's)
    world.write_text("[[marker]]\nid = 4\nx = 1.0\ny = 2.0\nz = 0.1\nsize = 0.1\nyaw = 0.0\n")
    assert inputs.read_map(str(world)) == ({4: (1.0, 2.0)}, "world mine")
    world.write_text("[[marker]]\nid = 4\n")
    with pytest.raises(inputs.BadInput, match=r"mine.toml: marker\[0\]"):
        inputs.read_map(str(world))
    with pytest.raises(inputs.BadInput, match=r"aruco1_0: expected \{\"x\": number"):
        inputs.true_map(write(tmp_path, "t.txt", '{"aruco1_0": {"x": 1}}'))
    with pytest.raises(inputs.BadInput, match="no arucoN_0 markers"):
        inputs.true_map(write(tmp_path, "t.txt", '{"lemon_0": {"x": 1, "y": 2}}'))
    with pytest.raises(inputs.BadInput, match="nowhere"):
        inputs.true_map("nowhere")


def test_a_map_in_a_recording_the_last_one_on_its_key(tmp_path: Path) -> None:
    """A map key is outside the key table (a raw channel); camera/landmarks, with its own
    `landmarks` list, is not taken for a map, nor a bad sample after the last map."""
    path = tmp_path / "maps.mcap"
    first = {"landmarks": [{"id": 0, "x": 5.0, "y": 5.0}]}
    last = {"stamp": 2, "landmarks": [{"id": i, "x": x, "y": y} for i, (x, y) in LAB.items()]}
    w = BagWriter(path)
    w.write("icefloe/sim/camera/landmarks", codec.encode(m.Landmarks(stamp=1, landmarks=[
        m.Landmark(id=3, range=1.0, bearing=0.1)])), codec.MSGPACK, 1)
    w.write("icefloe/sim/slam/map", json.dumps(first).encode(), codec.JSON, 2)
    w.write("icefloe/sim/slam/map", msgspec.msgpack.encode(last), codec.MSGPACK, 3)
    w.write("icefloe/sim/slam/map", b"\xc1", codec.MSGPACK, 4)
    w.write("icefloe/sim/slam/map", b'{"hello": 1}', codec.JSON, 5)
    w.write("icefloe/sim/other", b'{"x": 1}', codec.JSON, 6)
    w.close()
    points, where = inputs.read_map(str(path))
    assert points == LAB and "icefloe/sim/slam/map" in where
    assert inputs.read_map(str(path), "slam/map")[0] == LAB
    with pytest.raises(BadRecording, match="no messages on odom/pose"):
        inputs.read_map(str(path), "odom/pose")
    with pytest.raises(inputs.BadInput, match="no landmark map on icefloe/sim/other"):
        inputs.read_map(str(path), "other")
    empty = tmp_path / "none.mcap"
    w = BagWriter(empty)
    w.write("icefloe/sim/odom/pose", codec.encode(m.Pose(stamp=1, x=0, y=0, theta=0)), codec.MSGPACK, 1)
    w.close()
    with pytest.raises(inputs.BadInput, match=r"none.mcap: no landmark map: --key KEY"):
        inputs.read_map(str(empty))


# --------------------------------------------------------------------------- trajectories


def line(n: int = 201, step: float = 0.01, rate: float = 50.0) -> Trajectory:
    """Along +x, ``step`` m apart, at ``rate`` Hz."""
    return Trajectory.of([(k / rate, k * step, 0.0, 0.0) for k in range(n)])


def test_a_constant_offset_scores_zero_ate_and_zero_rpe_after_alignment() -> None:
    truth = Trajectory.of([(k * 0.02, math.cos(k * 0.01), math.sin(k * 0.01) + 0.001 * k, k * 0.01 + math.pi / 2)
                           for k in range(400)])
    frame = Alignment(rotation=0.6, translation=(1.5, -0.3))
    xy = frame.apply(truth.xy())
    est = Trajectory.of(np.column_stack([truth.t, xy, truth.theta + 0.6]))
    score = score_path(est, truth)
    assert score.pairs == 400 and score.unmatched == 0
    assert score.ate_rmse < 1e-9 and score.ate_max < 1e-9 and score.heading_rmse < 1e-9
    assert score.ate_rmse_raw > 1.0
    assert score.segments > 0 and score.rpe_translation < 1e-7 and score.rpe_rotation < 1e-7


def test_a_scale_drift_of_2_percent_is_an_rpe_of_2_percent() -> None:
    truth = line()
    est = Trajectory.of(np.column_stack([truth.t, truth.x * 1.02, truth.y, truth.theta]))
    score = score_path(est, truth, segment=0.5)
    assert score.rpe_translation == pytest.approx(2.0, rel=1e-6)
    assert score.rpe_rotation == pytest.approx(0.0, abs=1e-9)
    assert score.distance == pytest.approx(2.0) and score.segments == 151  # starts 0 .. 1.5 m
    assert score_path(est, truth, kind="similarity").ate_rmse < 1e-9  # a scale is what a similarity removes


def test_a_turning_drift_of_kappa_rad_per_metre_is_its_rpe() -> None:
    """The truth goes straight; the estimate turns kappa rad per metre as it goes (dead reckoning with a
    bias), so every 1 m of it is an arc: rotation error kappa (in deg/m), translation error the gap
    between the arc's end, (sin k / k, (1 - cos k) / k), and the straight line's, (1, 0)."""
    kappa, step = 0.05, 0.01
    truth = line(401, step)
    est_rows, x, y, th = [], 0.0, 0.0, 0.0
    for k in range(401):
        est_rows.append((truth.t[k], x, y, th))
        x += math.sin(th + kappa * step) / kappa - math.sin(th) / kappa  # exact arc of length `step`
        y += -math.cos(th + kappa * step) / kappa + math.cos(th) / kappa
        th += kappa * step
    score = score_path(Trajectory.of(est_rows), truth, segment=1.0)
    gap = math.hypot(math.sin(kappa) / kappa - 1.0, (1 - math.cos(kappa)) / kappa)
    assert score.rpe_rotation == pytest.approx(math.degrees(kappa), rel=1e-6)  # 2.865 deg/m
    assert score.rpe_translation == pytest.approx(100 * gap, rel=1e-6)  # 2.50 %
    assert score.segments == 301


def test_association_takes_the_nearest_true_pose_within_the_tolerance() -> None:
    truth_t = np.arange(0.0, 1.0, 0.02)  # 50 Hz
    est_t = np.array([0.005, 0.011, 0.049, 0.5, 2.0])
    i, j = associate(est_t, truth_t, 0.02)
    # 0.005 -> 0.00; 0.011 -> 0.02 (nearest); 0.049 -> 0.04 (0.06 is 0.011 away, 0.04 0.009); 0.5 -> 0.50; 2.0 none
    assert list(i) == [0, 1, 2, 3] and list(truth_t[j]) == pytest.approx([0.0, 0.02, 0.04, 0.5])
    # Two estimates nearest the same true pose: the nearer keeps it.
    i, j = associate(np.array([0.017, 0.021]), truth_t, 0.02)
    assert list(i) == [1] and list(j) == [1]
    assert len(associate(np.array([5.0]), truth_t, 0.02)[0]) == 0
    assert len(associate(np.array([0.0]), np.array([0.0]), 0.02)[0]) == 1


def test_poses_with_the_same_stamp_keep_the_last_one_given() -> None:
    t = Trajectory.of([(1.0, 0.0, 0.0, 0.0), (0.5, 9.0, 9.0, 0.0), (1.0, 1.0, 1.0, 0.0)])
    assert list(t.t) == [0.5, 1.0] and list(t.x) == [9.0, 1.0]


def test_trajectories_that_do_not_overlap_in_time_say_so() -> None:
    truth = line()
    late = Trajectory.of(np.column_stack([truth.t + 100, truth.x, truth.y, truth.theta]))
    with pytest.raises(NotEnough, match=r"0 poses are within 0.02 s of a true pose"):
        score_path(late, truth)


def test_a_path_shorter_than_a_segment_has_no_rpe() -> None:
    truth = line(11)  # 0.1 m
    score = score_path(truth, truth)
    assert score.segments == 0 and math.isnan(score.rpe_translation)


# --------------------------------------------------------------------------- trajectory files, hostile


def test_csv_columns_t_or_stamp_and_the_export_s_log_time(tmp_path: Path) -> None:
    a = inputs.read_csv(Path(write(tmp_path, "a.csv", "theta,x,y,t\n0.1,1,2,0.5\n0.2,3,4,0.25\n")))
    assert list(a.t) == [0.25, 0.5] and list(a.x) == [3.0, 1.0] and list(a.theta) == [0.2, 0.1]
    b = inputs.read_csv(Path(write(tmp_path, "b.csv", "log_time,stamp,x,y,theta,covariance\n"
                                                       "7,2000000000,1,2,0.5,\"[1, 0]\"\n")))
    assert list(b.t) == [2.0]  # stamp (ns) before log_time


@pytest.mark.parametrize(("content", "error"), [
    ("", "the header row has no column x, y, theta, t (s) or stamp (ns) (it has: nothing)"),
    ("time,x,y,theta\n", "no column t (s) or stamp (ns) (it has: time, x, y, theta)"),
    ("t,x,y\n0,0,0\n", "no column theta"),
    ("t,x,y,theta\n0,0,zero,0\n", "line 2: expected numbers in t, x, y, theta"),
    ("t,x,y,theta\n0,0,0\n", "line 2: expected numbers"),
    ("t,x,y,theta\n0,0,0,0\n1,nan,0,0\n", "pose 2 is (1.0, nan, 0.0, 0.0): not finite"),
    ("t,x,y,theta\n", "no poses"),
])
def test_a_bad_csv_is_one_error_naming_the_file(tmp_path: Path, content: str, error: str) -> None:
    path = write(tmp_path, "traj.csv", content)
    with pytest.raises(inputs.BadInput) as exc:
        inputs.read_trajectory(path, "loc/pose")
    assert str(exc.value).startswith(path) and error in str(exc.value), exc.value


def test_poses_in_a_recording_any_key_with_x_y_theta_and_a_stamp(tmp_path: Path, caplog) -> None:
    """loc/pose (typed) and an external localizer's key outside the key table (raw, JSON); a
    message without a stamp takes the time it was recorded; a message that is no pose is skipped,
    with one warning."""
    path = tmp_path / "run.mcap"
    w = BagWriter(path)
    for k in range(5):
        stamp = 1_000_000_000 + k * 20_000_000
        w.write("icefloe/sim/loc/pose", codec.encode(m.PoseEstimate(stamp=stamp, x=k * 0.1, y=0, theta=0,
                                                                    covariance=[0.0] * 9)), codec.MSGPACK, stamp)
        w.write("icefloe/sim/extloc/pose", json.dumps({"x": k * 0.1, "y": 0.0, "theta": 0.0}).encode(),
                codec.JSON, stamp + 1000)
    w.write("icefloe/sim/loc/pose", b"\xc1 not a pose", codec.MSGPACK, 1_050_000_000)  # a raw channel, same key
    w.write("icefloe/sim/bad/pose", json.dumps({"x": 1.0, "y": 0.0}).encode(), codec.JSON, 1)
    w.close()
    loc, where = inputs.read_trajectory(str(path), "loc/pose")
    assert len(loc) == 5 and loc.t[0] == pytest.approx(1.0) and "icefloe/sim/loc/pose" in where
    assert [r.getMessage() for r in caplog.records] == [
        f"{path}: icefloe/sim/loc/pose: a message does not decode: MessagePack data is malformed: invalid opcode "
        "'\\xc1' (byte 0) (1 message skipped)"]
    ext, _ = inputs.read_trajectory(str(path), "extloc/pose")
    assert ext.t[1] == pytest.approx(1.020001)
    assert score_path(loc, ext).ate_rmse < 1e-12
    with pytest.raises(inputs.BadInput, match="bad/pose: no poses"):
        inputs.read_trajectory(str(path), "icefloe/sim/bad/pose")
    assert "bad/pose: a message has no 'theta'" in caplog.records[-1].getMessage()
    with pytest.raises(BadRecording, match=r"no messages on sim/truth \(it has icefloe/sim/bad/pose"):
        inputs.read_trajectory(str(path), "sim/truth")
