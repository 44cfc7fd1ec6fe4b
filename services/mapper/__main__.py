"""mapper: map making with a known pose, from ``camera/landmarks`` to ``map/landmarks``.

* The known pose: ``mapper.pose`` = ``"extloc/pose"`` (an external localizer: motion capture,
  an overhead camera) or ``"sim/truth"`` (the simulator's).
* The maths is in `mapping.py` (one small module: read it first): each landmark its own
  EKF, its position and 2 x 2 covariance.
* Publishes ``map/landmarks`` at ``mapper.rate_hz`` once it has a landmark.

Run: ``python -m icefloe.services.mapper --config sim``; a robot config runs it under
``icefloe up`` when its ``services`` list names ``mapper`` (docs/slam.md).
"""

from __future__ import annotations

import asyncio

from icefloe.config import RobotConfig
from icefloe.runtime import Node, run
from icefloe.schemas import keys

from .tracker import Mapper


async def main(config: RobotConfig) -> None:
    async with Node("mapper", config) as node:
        mapper = Mapper(config, node.log)
        source = keys.TABLE[config.mapper.pose]
        pub = node.publisher(keys.MAP_LANDMARKS)
        node.log.info("mapper: known pose from %s, publishing %s", node.key(source), node.key(keys.MAP_LANDMARKS))

        async def poses() -> None:
            async for pose in node.subscribe(source, latest=False, maxsize=64):
                mapper.on_pose(pose)

        async def landmarks() -> None:
            async for frame in node.subscribe(keys.LANDMARKS, latest=False, maxsize=16):
                mapper.on_landmarks(frame)

        async def steady() -> None:
            while True:
                await asyncio.sleep(1.0 / config.mapper.rate_hz)
                if mapper.mapper.mean:
                    pub.put(mapper.landmark_map())

        async with asyncio.TaskGroup() as tasks:
            for job in (poses, landmarks, steady):
                tasks.create_task(job())


if __name__ == "__main__":
    run(main)
