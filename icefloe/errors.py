"""Errors with names.

Every error icefloe raises on purpose is one of these. Messages name the thing
that was wrong (the key, the field, the port, the config key) so that a student
reading a log line knows where to look.
"""


class IcefloeError(Exception):
    """Base class of every icefloe error."""


class ConfigError(IcefloeError):
    """A robot config file is missing, unreadable or has a bad value.

    The message names the file and the key, e.g.
    ``deploy/robots/x.toml: hwbridge.rate_hz: Expected `int`, got `str```.
    """


class BadPayload(IcefloeError):
    """A bus payload could not be decoded into the message its key carries.

    The message names the key expression and the field, e.g.
    ``icefloe/sim/cmd/twist: Expected `float`, got `str` - at `$.v```.
    """


class UnknownKey(IcefloeError):
    """A key expression is not in the key table (`icefloe.schemas.keys`)."""


class BoardError(IcefloeError):
    """The I/O board (PenguinPi serial or icoBoard SPI) misbehaved or is absent.

    The message names the port or device, e.g. ``/dev/serial0: no reply``.
    """


class BoardMismatch(BoardError):
    """The board's START descriptor does not match the robot config; we refuse to run."""


class GatewareError(IcefloeError):
    """The icoBoard gateware cannot be made: a peripheral list it cannot build, a failed
    toolchain step, or a design that does not meet its clock (``icefloe gateware build``)."""


class NotReachable(IcefloeError):
    """A robot (its Zenoh router or a queryable) did not answer in time."""


class NotConfirmed(IcefloeError):
    """hwbridge could not confirm that the wheels stopped: the board did not answer in time,
    or a newer motion command released the stop first. The message says which."""


class BadRecording(IcefloeError):
    """An MCAP recording cannot be read, or a channel of it cannot be replayed.

    The message names the file and, where it is about one, the channel's topic, e.g.
    ``run.mcap: not an MCAP file (it starts with b'PK\\x03\\x04')``.
    """


class MotionError(IcefloeError):
    """A closed-loop motion (`Robot.forward`, `Robot.turn`) did not get there; the robot is stopped."""


class MotionTimeout(MotionError, TimeoutError):
    """The motion was not done within its timeout (a blocked wheel, a speed the motors cannot hold).

    The message says how far it got, e.g. ``forward(0.5 m): 0.12 m done after 6.0 s (timeout)``.
    """


class MotionStopped(MotionError):
    """Something else ended the motion first: a ``cmd/stop`` from another program, or another
    command from this one."""
