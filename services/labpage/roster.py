"""What the lab's page knows of each robot: alive or not, held or not, what it last answered.

Fed from the bus by the service (``__main__``): the robots' hwbridge liveliness tokens, their
``hw/hold`` and the answers to the TA's stops. No bus, no clock here: tests feed it by hand.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from icefloe.labstop import Answer
from icefloe.schemas import keys
from icefloe.schemas import messages as m

MAX_ROBOTS = 500
"""Robots the roster remembers beyond the lab's own (names seen on the bus): a flood of made-up
tokens cannot grow it without bound."""


@dataclass
class RobotRow:
    name: str
    in_folder: bool
    """One of the lab's robots (its credentials file is in the lab's folder)."""
    alive: bool = False
    """Its hwbridge holds its liveliness token now."""
    hold: m.Hold | None = None
    """What its hwbridge last said on ``hw/hold``."""
    last: Answer | None = None
    """Its answer to the TA's last stop, hold or release."""

    def to_json(self) -> dict[str, object]:
        last = None
        if self.last is not None:
            last = {"confirmed": self.last.confirmed, "held": self.last.held, "line": self.last.line(),
                    "ms": None if self.last.seconds is None else round(self.last.seconds * 1e3, 1)}
        hold = self.hold
        return {"name": self.name, "in_folder": self.in_folder, "alive": self.alive,
                "held": bool(hold and hold.held), "since": hold.since if hold else 0,
                "reason": hold.reason if hold else "", "owner_may_release": bool(hold and hold.owner_may_release),
                "last": last}


@dataclass
class Roster:
    """Every robot of the lab (``folder``) and every robot heard of on the bus."""

    folder: list[str]
    rows: dict[str, RobotRow] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rows = {name: RobotRow(name, True) for name in sorted(self.folder)}

    def _row(self, robot: str) -> RobotRow | None:
        row = self.rows.get(robot)
        if row is None and len(self.rows) < len(self.folder) + MAX_ROBOTS:
            row = self.rows[robot] = RobotRow(robot, False)
        return row

    def token(self, key_expr: str, alive: bool) -> None:
        """A liveliness token came (``alive``) or went: ``icefloe/<robot>/alive/hwbridge``."""
        who = keys.alive_of(key_expr)
        if who is None or who[1] != "hwbridge":
            return
        row = self.rows.get(who[0]) if not alive else self._row(who[0])
        if row is not None:
            row.alive = alive

    def hold(self, key_expr: str, hold: m.Hold) -> None:
        """``icefloe/<robot>/hw/hold`` (a concrete key only)."""
        if not keys.is_concrete(key_expr):
            return
        robot, _ = keys.split(key_expr)
        row = self._row(robot)
        if row is not None:
            row.hold = hold

    def answered(self, answers: Iterable[Answer]) -> None:
        for answer in answers:
            row = self._row(answer.robot)
            if row is not None:
                row.last = answer

    def known(self) -> list[str]:
        """The robots a stop of "every robot" asks: the lab's, and every other one alive."""
        return sorted(name for name, row in self.rows.items() if row.in_folder or row.alive)

    def to_json(self) -> list[dict[str, object]]:
        return [row.to_json() for _, row in sorted(self.rows.items())]
