"""The simulated PenguinPi board: the firmware model behind a pseudo-terminal.

    world = World(config.geometry)
    board = PenguinPiSim(world, config.board)      # host opens config.board.serial_port
    ...  # the simulator's clock: world.step(0.001); board.tick(now), 1000 times a second
    board.model.hat.press("S4")                    # test handles live on .model
    board.close()

The host side (hwbridge) cannot tell this from the real board: it opens
``board.serial_port`` with pyserial, and gets the firmware's bytes, at the
firmware's pace. See docs/sim-penguinpi.md.
"""

from __future__ import annotations

from icefloe.config import Board

from .penguinpi_firmware import Defects, PenguinPiFirmware
from .pty_link import LineFaults, PtyLink
from .world import World


class PenguinPiSim:
    """The firmware model (`model`) wired to a paced pseudo-terminal (`link`)."""

    def __init__(self, world: World, board: Board, *, fixed_firmware: bool = False,
                 defects: Defects | None = None, dip: int = 0b0001, seed: int = 1) -> None:
        """``fixed_firmware``: correct every known firmware defect (facts §8);
        ``defects``: choose them one by one instead. ``dip``: the DIP switches at
        power-on (default SW4 on: velocity control). ``seed``: for line noise."""
        if defects is None:
            defects = Defects.fixed() if fixed_firmware else Defects()
        self.model = PenguinPiFirmware(world, defects=defects, dip=dip, baud=board.baud)
        self.model.line = LineFaults(seed)
        self.link = PtyLink(board.serial_port, board.baud, self.model.receive, self.model.poll,
                            faults=self.model.line)
        # Connect the output only now: the boot line goes out through the link.
        self.model.transmit = self.link.send
        self.model.start()

    @property
    def path(self) -> str:
        """The pseudo-terminal the host opens (the target of ``board.serial_port``)."""
        return self.link.slave_name

    def tick(self, now: float) -> None:
        """One simulated millisecond (call after ``world.step(0.001)``)."""
        self.model.tick(now)

    def close(self) -> None:
        self.link.close()
