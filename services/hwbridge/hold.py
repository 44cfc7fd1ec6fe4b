"""The lab's hold: the TA's stop that lasts until it is released (``lab/stop``, docs/lab.md).

While a robot is held, hwbridge refuses every motion command (`Bridge.command`, `Bridge.motion`):
a student's program that keeps sending ``cmd/twist`` cannot drive it. Only a ``lab/stop``
"release" ends the hold (the lab's TA: only the TA may ask ``lab/stop``), or the owner's
``cmd/release`` when the TA allowed it.

The hold outlives hwbridge: it is kept in a file of the robot's private run folder, so a
hwbridge that is restarted (its real-time cycle died, `icefloe up` restarted it) comes back
held. A reboot clears the run folder, and with it the hold.

Pure state, no bus and no clock: times are arguments, so tests drive it exactly.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import msgspec

from icefloe.schemas import messages as m


class HoldState:
    """Whether the robot is held, since when, why, and who may release it."""

    def __init__(self, path: Path | None = None) -> None:
        """``path``: where the hold is kept across restarts (None: in memory only). A hold found
        there is taken up; a file that cannot be read holds the robot (reason says so): a hold
        must not be lost to a damaged file."""
        self.path = path
        self.error = ""
        """Why the last change could not be kept in ``path`` ("" = it was)."""
        self.state = m.Hold(stamp=0, held=False)
        if path is not None and path.exists():
            try:
                self.state = msgspec.json.decode(path.read_bytes(), type=m.Hold)
            except (OSError, msgspec.DecodeError, msgspec.ValidationError, ValueError):
                self.state = m.Hold(stamp=0, held=True, reason=f"(unreadable {path.name}: held)")

    @property
    def held(self) -> bool:
        return self.state.held

    def hold(self, now_ns: int, reason: str, owner_may_release: bool) -> bool:
        """Hold the robot (a hold already in place keeps its start, takes the new words); returns
        whether it was not held before."""
        new = not self.state.held
        since = now_ns if new else self.state.since
        self.state = m.Hold(stamp=now_ns, held=True, since=since, reason=reason, owner_may_release=owner_may_release)
        self._keep()
        return new

    def release(self, now_ns: int) -> bool:
        """End the hold; returns whether there was one."""
        was = self.state.held
        self.state = m.Hold(stamp=now_ns, held=False)
        self._keep()
        return was

    def owner_may_release(self) -> bool:
        return self.state.held and self.state.owner_may_release

    def message(self, now_ns: int) -> m.Hold:
        """``hw/hold`` now."""
        return msgspec.structs.replace(self.state, stamp=now_ns)

    def refusal(self) -> str:
        """Why a motion command is not applied while held (for its rate-limited log line)."""
        said = f" ({self.state.reason})" if self.state.reason else ""
        who = "the TA or its owner (cmd/release)" if self.state.owner_may_release else "the lab's TA"
        return f"the robot is held stopped by the lab's TA{said} until {who} releases it"

    def _keep(self) -> None:
        """Write the hold to ``path`` (replaced whole: a crash leaves the old file or the new),
        or remove the file when released; a failure is kept in `error`, the hold stays in force."""
        self.error = ""
        if self.path is None:
            return
        try:
            if not self.state.held:
                with contextlib.suppress(FileNotFoundError):
                    self.path.unlink()
                return
            fresh = self.path.with_name(self.path.name + ".new")
            fresh.write_bytes(msgspec.json.encode(self.state))
            os.replace(fresh, self.path)
        except OSError as exc:
            self.error = f"{type(exc).__name__}: {exc.strerror or exc}"
