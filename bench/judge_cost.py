"""What the lap judge costs per truth sample, next to decoding that sample (done anyway).

    .venv/bin/python bench/judge_cost.py [--world track] [--laps 3]

In this process: ``--laps`` laps of the world's track along its centerline at 0.2 m/s, sampled at
the simulator's truth rate (50 Hz), each stopping 1 s with the front 5 cm before each stop line;
the judge (`services/judge/scoring.py`) takes every sample. Printed: CPU time per sample and what
that is at 50 Hz (% of a core here, and in Pi 3B cores, 6.4x slower: docs/deploy.md), next to the
time msgspec takes to decode one ``sim/truth`` payload, measured in the same run; and the laps as
the judge scored them (a clean lap: no penalty, the 5 s reward).
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from icefloe.schemas import codec
from icefloe.schemas import messages as m
from icefloe.services.judge.scoring import Judge, Rules
from icefloe.worldmap import load_world

RATE_HZ = 50.0
SPEED = 0.2
PI3B_FACTOR = 6.4
"""How much slower a Pi 3B core is than this machine's (docs/deploy.md)."""


def lap_samples(track, laps: int) -> list[tuple[float, float, float, float]]:  # type: ignore[no-untyped-def]
    """(t, x, y, theta) along the centerline, laps times round, stopping before each stop line."""
    line = track.centerline()
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
    length = arc[-1]
    stops = sorted(float(arc[np.argmin(np.hypot(*(line - [s.stop_x, s.stop_y]).T))]) - Rules().radius - 0.05
                   for s in track.signs)
    samples, t, s = [], 0.0, -0.1
    end = laps * length + 0.1
    pending = [lap * length + x for lap in range(laps) for x in stops]
    while s < end:
        along = s % length if s >= 0 else s
        i = int(np.clip(np.searchsorted(arc, along), 1, len(arc) - 1))
        x, y = (np.interp(along, arc, line[:, k]) for k in (0, 1))
        if s < 0:
            x, y = line[0] + (line[1] - line[0]) / np.linalg.norm(line[1] - line[0]) * s
        dx, dy = line[i] - line[i - 1]
        samples.append((t, float(x), float(y), math.atan2(dy, dx)))
        t += 1 / RATE_HZ
        if pending and s >= pending[0]:
            pending.pop(0)
            samples.extend((t + k / RATE_HZ, float(x), float(y), math.atan2(dy, dx)) for k in range(int(RATE_HZ)))
            t += 1.0
        s += SPEED / RATE_HZ
    return samples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--world", default="track", help="a world with a track (name or path)")
    parser.add_argument("--laps", type=int, default=3, help="laps to drive")
    args = parser.parse_args()
    track = load_world(args.world).track
    if track is None:
        raise SystemExit(f"{args.world}: track: the world has no track")
    samples = lap_samples(track, args.laps)
    payloads = [codec.encode(m.Truth(stamp=int(1e18 + t * 1e9), x=x, y=y, theta=th)) for t, x, y, th in samples]
    judge = Judge(track)
    c0 = time.process_time()
    for sample in samples:
        judge.feed(*sample)
    judge_s = (time.process_time() - c0) / len(samples)
    c0 = time.process_time()
    for payload in payloads:
        codec.decode(payload, codec.MSGPACK, m.Truth)
    decode_s = (time.process_time() - c0) / len(payloads)
    load = os.getloadavg()[0]
    print(f"judge on {track.name} ({track.lap_length():.2f} m a lap, {len(track.signs)} stop signs), "
          f"{len(samples)} truth samples at {RATE_HZ:.0f} Hz; load average {load:.1f}")
    for what, seconds in (("judge.feed", judge_s), ("decode sim/truth (reference)", decode_s)):
        share = seconds * RATE_HZ * 100
        print(f"  {what:<30} {seconds * 1e6:8.1f} us/sample  {share:6.2f} % of a core at 50 Hz"
              f"  ({share * PI3B_FACTOR / 100:.3f} Pi 3B cores)")
    for lap in judge.finished:
        print(f"  lap {lap.number}: {lap.time(judge.now):.2f} s + {lap.penalties:.0f} s - {lap.reward:.0f} s"
              f" = {lap.score(judge.now):.2f} s")


if __name__ == "__main__":
    main()
