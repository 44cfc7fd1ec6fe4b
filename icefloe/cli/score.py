"""``icefloe score map`` and ``icefloe score path``: a landmark map or a trajectory against the truth.

The maths is in `icefloe.score.maths`, the readers in `icefloe.score.inputs`; this module picks
the sources (a file, a recording or a live key), reads live keys, and prints. docs/score.md is the guide.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..config import RobotConfig
from ..errors import IcefloeError
from ..runtime import RawSample, run_async
from ..schemas import codec
from ..score import inputs
from ..score.maths import ALIGNMENTS, Alignment, NotEnough, PathScore, Trajectory, score_map, score_path
from .common import add_bus_arguments, bus_config, check_robot, cli_node, key_names, resolve_key, warn
from .record import warnings_to_stderr

FILE_SUFFIXES = {".txt", ".json", ".msgpack", ".mcap", ".csv", ".toml"}
MAX_LIVE_POSES = 1_000_000
"""Poses kept of a live key at most (5.5 hours at 50 Hz): a flood fills no more memory than that."""


def is_file(source: str) -> bool:
    """Is ``source`` a file (or meant to be one: a path, or a name with a file's suffix), not a bus key?"""
    path = Path(source).expanduser()
    return path.exists() or path.suffix in FILE_SUFFIXES or source.startswith(("./", "../", "/", "~"))


def robot_of(args: argparse.Namespace, config: RobotConfig) -> str:
    return args.robot or config.name


def one_key(args: argparse.Namespace, source: str, what: str) -> str:
    """The full key ``source`` names on the robot of ``args``; `IcefloeError` for a wildcard (``what``
    is read from one key)."""
    key = resolve_key(source, robot_of(args, bus_config(args)))
    if "*" in key:
        raise IcefloeError(f"{source}: {what} is read from one key, not a wildcard")
    return key


# --------------------------------------------------------------------------- live keys


async def first_sample(args: argparse.Namespace, key: str) -> RawSample:
    """One sample of ``key``, within ``args.timeout`` s."""
    config = bus_config(args)
    async with cli_node(config) as node:
        sub = node.subscribe_raw(key)
        if problem := check_robot(await node.alive("*"), robot_of(args, config)):
            warn(problem)
        try:
            return await asyncio.wait_for(anext(sub), args.timeout)
        except TimeoutError:
            raise IcefloeError(f"{key}: nothing published within {args.timeout:g} s") from None


def decoded(raw: RawSample) -> Any:
    try:
        return codec.to_builtins(raw.payload, raw.encoding)
    except Exception as exc:  # msgspec.DecodeError, BadPayload (an unknown encoding)
        raise inputs.BadInput(f"{raw.key}: a sample does not decode: {exc}") from None


async def collect(args: argparse.Namespace, live: list[str]) -> dict[str, list[tuple[float, float, float, float]]]:
    """Poses on each live key for ``args.duration`` s, or until Ctrl-C, or `MAX_LIVE_POSES` of one
    key; a sample that is no pose is skipped, with one line for the first of each key."""
    config = bus_config(args)
    rows: dict[str, list[tuple[float, float, float, float]]] = {k: [] for k in live}
    bad: set[str] = set()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()

    async def take(sub: Any, key: str) -> None:
        async for raw in sub:
            if len(rows[key]) >= MAX_LIVE_POSES:
                warn(f"{key}: {MAX_LIVE_POSES} poses: scoring these, the rest are not kept")
                stop.set()
                return
            try:
                rows[key].append(inputs.pose_row(decoded(raw), time.time_ns(), raw.key))
            except inputs.BadInput as exc:
                if key not in bad:
                    bad.add(key)
                    warn(f"{exc} (skipped)")

    async with cli_node(config) as node:
        tasks = [asyncio.create_task(take(node.subscribe_raw(k, maxsize=100_000), k)) for k in live]
        if problem := check_robot(await node.alive("*"), robot_of(args, config)):
            warn(problem)
        print(f"collecting {', '.join(live)} for {args.duration:g} s (Ctrl-C scores what came so far)",
              file=sys.stderr, flush=True)
        loop.add_signal_handler(signal.SIGINT, stop.set)
        try:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), args.duration)
        finally:
            loop.remove_signal_handler(signal.SIGINT)
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
    return rows


# --------------------------------------------------------------------------- score map


def read_map(args: argparse.Namespace) -> tuple[inputs.Points, str]:
    if is_file(args.map):
        return inputs.read_map(args.map, args.key)
    key = one_key(args, args.map, "one map")
    raw = run_async(first_sample(args, key))
    return inputs.map_points(decoded(raw), key), f"{key} (one sample)"


def map_verb(args: argparse.Namespace) -> int:
    warnings_to_stderr()
    estimate, source = read_map(args)
    truth, truth_source = inputs.true_map(args.world)
    if not estimate:
        raise inputs.BadInput(f"{source}: the map is empty: nothing to score")
    try:
        score = score_map(estimate, truth, args.align)
    except NotEnough as exc:
        raise inputs.BadInput(f"{source}: {len(set(estimate) & set(truth))} of its {len(estimate)} markers are "
                              f"in {truth_source}: {exc}") from None
    a = score.alignment
    if args.json:
        print(json.dumps({
            "map": source, "truth": truth_source, "matched": len(score.errors),
            "alignment": alignment_json(a), "rmse": score.rmse, "rmse_before": score.rmse_raw,
            "markers": {str(i): {"error": e, "x": score.aligned[i][0], "y": score.aligned[i][1],
                                 "true_x": truth[i][0], "true_y": truth[i][1]} for i, e in score.errors.items()},
            "missed": score.missed, "spurious": score.spurious}))
        return 0
    print(f"map:       {source}, {len(estimate)} markers")
    print(f"truth:     {truth_source}, {len(truth)} markers")
    print(f"alignment: {describe_alignment(a)}, on {len(score.errors)} markers in both")
    print(f"RMSE:      {score.rmse:.3f} m after alignment ({score.rmse_raw:.3f} m before)")
    print("\n  id  error m   x (aligned)  y (aligned)   x (true)  y (true)")
    for i, e in score.errors.items():
        (x, y), (tx, ty) = score.aligned[i], truth[i]
        print(f"{i:>4}  {e:7.3f}  {x:11.3f}  {y:11.3f}  {tx:9.3f}  {ty:8.3f}")
    print(f"\nmissed:    {ids(score.missed)} (in the world, not in the map)")
    print(f"spurious:  {ids(score.spurious)} (in the map, not in the world)")
    return 0


def ids(values: list[int]) -> str:
    return ", ".join(map(str, values)) or "none"


def alignment_json(a: Alignment) -> dict[str, Any]:
    return {"kind": a.kind, "rotation": a.rotation, "translation": a.translation, "scale": a.scale}


def describe_alignment(a: Alignment) -> str:
    if a.kind == "none":
        return "none (as given)"
    scale = f", scale {a.scale:.4f}" if a.kind == "similarity" else ""
    return (f"{a.kind}: rotation {math.degrees(a.rotation):+.2f} deg, translation "
            f"({a.translation[0]:+.3f}, {a.translation[1]:+.3f}) m{scale}")


# --------------------------------------------------------------------------- score path


def read_paths(args: argparse.Namespace) -> tuple[tuple[Trajectory, str], tuple[Trajectory, str]]:
    sources = [(args.traj, args.key), (args.truth, args.truth_key)]
    out: list[tuple[Trajectory, str] | None] = [None, None]
    live: dict[int, str] = {}
    for n, (source, key) in enumerate(sources):
        if is_file(source):
            out[n] = inputs.read_trajectory(source, key)
        else:
            live[n] = one_key(args, source, "a trajectory")
    if live:
        rows = run_async(collect(args, sorted(set(live.values()))))
        for n, full in live.items():
            out[n] = inputs.trajectory_of(rows[full], full), f"{full} (live)"
    assert out[0] is not None and out[1] is not None
    return out[0], out[1]


def path_verb(args: argparse.Namespace) -> int:
    warnings_to_stderr()
    (est, est_source), (truth, truth_source) = read_paths(args)
    try:
        score = score_path(est, truth, max_dt=args.max_dt, kind=args.align, segment=args.segment)
    except NotEnough as exc:
        raise inputs.BadInput(f"{est_source} against {truth_source}: {exc}") from None
    if args.json:
        print(json.dumps(path_json(score, est_source, truth_source, len(est), len(truth))))
        return 0
    a = score.alignment
    print(f"trajectory: {est_source}, {len(est)} poses over {est.t[-1] - est.t[0]:.1f} s")
    print(f"truth:      {truth_source}, {len(truth)} poses over {truth.t[-1] - truth.t[0]:.1f} s")
    print(f"associated: {score.pairs} poses, each within {args.max_dt:g} s of a true pose "
          f"({score.unmatched} without one)")
    print(f"alignment:  {describe_alignment(a)}")
    print(f"ATE:        RMSE {score.ate_rmse:.3f} m, mean {score.ate_mean:.3f} m, max {score.ate_max:.3f} m after "
          f"alignment (RMSE {score.ate_rmse_raw:.3f} m before); "
          f"heading RMSE {math.degrees(score.heading_rmse):.2f} deg")
    if score.segments:
        print(f"RPE:        {score.rpe_translation:.2f} % of distance travelled, {score.rpe_rotation:.3f} deg/m "
              f"({score.segments} segments of {score.segment:g} m; {score.distance:.2f} m travelled)")
    else:
        print(f"RPE:        none: the true path is {score.distance:.2f} m long, shorter than one segment "
              f"({score.segment:g} m; --segment shortens it)")
    return 0


def path_json(score: PathScore, est_source: str, truth_source: str, n_est: int, n_truth: int) -> dict[str, Any]:
    a = score.alignment

    def number(v: float) -> float | None:
        return None if math.isnan(v) else v

    return {"trajectory": est_source, "truth": truth_source, "poses": n_est, "true_poses": n_truth,
            "pairs": score.pairs, "unmatched": score.unmatched,
            "alignment": alignment_json(a),
            "ate": {"rmse": score.ate_rmse, "mean": score.ate_mean, "max": score.ate_max,
                    "rmse_before": score.ate_rmse_raw, "heading_rmse_deg": math.degrees(score.heading_rmse)},
            "rpe": {"segment": score.segment, "segments": score.segments, "distance": score.distance,
                    "translation_pct": number(score.rpe_translation),
                    "rotation_deg_per_m": number(score.rpe_rotation)}}


# --------------------------------------------------------------------------- the parsers


def positive(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, not {text!r}")
    return value


def add_key_option(parser: argparse.ArgumentParser, flag: str, help_: str, default: str | None = None) -> None:
    action = parser.add_argument(flag, default=default, metavar="KEY", help=help_)
    action.completer = key_names  # type: ignore[attr-defined]


def add_common(parser: argparse.ArgumentParser) -> None:
    """The options both verbs share: the alignment, --json, and the bus (for keys)."""
    parser.add_argument("--align", choices=ALIGNMENTS, default="rigid",
                        help="how the estimate is aligned to the truth first: rigid (rotation + translation, as "
                        "ECE4078's SLAM_eval.py), similarity (and scale), none (default rigid)")
    parser.add_argument("--json", action="store_true", help="print one JSON object (for scripts)")
    add_bus_arguments(parser)


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("score", help="score a landmark map or a trajectory against the truth",
                         description="Score a landmark map against the world's markers, or a pose trajectory "
                         "against the simulator's truth or an external localizer (docs/score.md).")
    score_verbs = p.add_subparsers(dest="score_verb", required=True, metavar="VERB", help="map, path")

    add_verb(score_verbs, "map", map_verb, map_options,
             help_="a landmark map against the world's true markers: RMSE after alignment, per marker",
             description="A landmark map against the world's true markers: aligned (Umeyama), then the RMSE, each "
             "marker's error, the markers missed and the spurious ones. MAP is a file (ECE4078's slam.txt, or "
             "icefloe's landmark map as JSON or MessagePack, a world file), a recording (the last map in it), or a "
             "bus key (one sample).",
             scored=("map", "MAP", "slam.txt, map.json, a world .toml, run.mcap, or a bus key (slam/map)"),
             truth=("--world", "WORLD", "the true markers: a world (lab, or a .toml file) or ECE4078's true map "
                    "(a JSON file)"))
    add_verb(score_verbs, "path", path_verb, path_options,
             help_="a trajectory against the truth: ATE after alignment, RPE per metre",
             description="A pose trajectory against the truth: poses associated by time (nearest within --max-dt), "
             "absolute trajectory error after alignment (RMSE, mean, max) and relative pose error per metre "
             "travelled (translation %%, rotation deg/m). TRAJ and TRUTH are each a CSV file (columns t or stamp, "
             "x, y, theta), a recording, or a bus key (collected for --duration).",
             scored=("traj", "TRAJ", "traj.csv, run.mcap, or a bus key (loc/pose)"),
             truth=("--truth", "TRUTH", "truth.csv, run.mcap, or a bus key (sim/truth, an external localizer's "
                    "pose key)"))


def add_verb(verbs: argparse._SubParsersAction, name: str, run: Callable[[argparse.Namespace], int],
             options: Callable[[argparse.ArgumentParser], None], *, help_: str, description: str,
             scored: tuple[str, str, str], truth: tuple[str, str, str]) -> None:
    """A score verb: what it scores (a positional: name, metavar, help), the truth (a required
    option: flag, metavar, help), the verb's own ``options``, then the options both share."""
    q = verbs.add_parser(name, help=help_, description=description)
    q.add_argument(scored[0], metavar=scored[1], help=scored[2])
    q.add_argument(truth[0], required=True, metavar=truth[1], help=truth[2])
    options(q)
    add_common(q)
    q.set_defaults(run=run)


def map_options(q: argparse.ArgumentParser) -> None:
    add_key_option(q, "--key", "in a recording: the map's key (default: the one key with maps)")
    q.add_argument("--timeout", type=positive, default=10.0, metavar="S",
                   help="a bus key: wait this long for a sample (default 10)")


def path_options(q: argparse.ArgumentParser) -> None:
    add_key_option(q, "--key", "in a recording TRAJ: the poses' key (default loc/pose)", "loc/pose")
    add_key_option(q, "--truth-key", "in a recording TRUTH: the true poses' key (default sim/truth)", "sim/truth")
    q.add_argument("--max-dt", type=positive, default=0.02, metavar="S",
                   help="associate poses at most S seconds apart (default 0.02: one period of sim/truth)")
    q.add_argument("--segment", type=positive, default=1.0, metavar="M",
                   help="RPE over segments of M metres of the true path (default 1)")
    q.add_argument("--duration", type=positive, default=30.0, metavar="S",
                   help="bus keys: collect for S seconds (default 30; Ctrl-C scores what came so far)")
