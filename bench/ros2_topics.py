"""What each ROS 2 topic of the ros2 service costs per message: its conversion (services/ros2's
`convert.outputs`) plus rosbags' CDR, in µs of one core, next to a reference measured in the same
run: msgspec decoding the icefloe message it is made from (what every subscriber pays anyway).

    .venv/bin/python bench/ros2_topics.py

Multiply by each key's rate for the share of a core: ``hw/wheels`` comes 100 times a second, so
``joint_states`` costs 100 x its figure each second (docs/ros2.md).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import msgspec

from icefloe import config as config_mod
from icefloe import ros2
from icefloe.schemas import codec
from icefloe.schemas import messages as m
from icefloe.services.ros2.convert import outputs

ROOT = Path(__file__).resolve().parent.parent
STAMP = 1_700_000_000_000_000_000
COVARIANCE = [0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.02]
SAMPLES: dict[str, m.Message] = {
    "odom/pose": m.Pose(stamp=STAMP, x=1.0, y=2.0, theta=0.5, v=0.1, w=0.2),
    "hw/wheels": m.Wheels(stamp=STAMP, ticks_left=1000, ticks_right=1020, speed_left=0.1, speed_right=0.12),
    "power/battery": m.Battery(stamp=STAMP, voltage=7.9, current=0.4, state="ok"),
    "loc/pose": m.PoseEstimate(stamp=STAMP, x=1.0, y=2.0, theta=0.5, covariance=COVARIANCE),
    "extloc/pose": m.ExternalPose(stamp=STAMP, x=1.0, y=2.0, theta=0.5, covariance=COVARIANCE),
    "camera/landmarks": m.Landmarks(stamp=STAMP, landmarks=[
        m.Landmark(id=i, range=1.0, bearing=0.1, position=[0.1, 0.0, 1.0], rotation=[0.0, math.pi, 0.0])
        for i in range(3)]),
    "camera/image": m.Image(stamp=STAMP, width=320, height=240, data=bytes(20_000)),  # a 320x240 JPEG's size
    "map/grid": m.OccupancyGrid(stamp=STAMP, world="lab", resolution=0.02, origin_x=0.0, origin_y=0.0, width=150,
                                height=150, inflation=0.0, cells=bytes(150 * 150)),
}


def per_message_us(function, arg, seconds: float = 0.3) -> float:
    count, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for _ in range(20):
            function(arg)
        count += 20
    return elapsed / count * 1e6


def main() -> None:
    config = config_mod.load(ROOT / "deploy" / "robots" / "sim.toml")
    config = msgspec.structs.replace(config, services=[*config.services, "grid"])  # map too
    print(f"{'ROS 2 topic':<30} {'from':<18} {'turn + CDR':>11} {'reference: msgspec decode':>26}")
    for output in outputs(config):
        sample = SAMPLES[output.key.name]
        encoded = codec.encode(sample)

        def publish(msg, output=output):
            return ros2.to_cdr(output.message(msg), output.ros_type, config.ros2.distro)

        def decode(data, topic=output.key):
            return codec.decode(data, "application/msgpack", topic.type if topic.kind != "query" else topic.reply)

        print(f"{output.topic:<30} {output.key.name:<18} {per_message_us(publish, sample):>8.0f} µs "
              f"{per_message_us(decode, encoded):>23.1f} µs")


if __name__ == "__main__":
    main()
