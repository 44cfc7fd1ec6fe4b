"""The icoBoard as an Amaranth platform, and where each signal goes on it (the pin map).

amaranth-boards 0.0.21 has no icoBoard, so it is defined here: a Lattice iCE40
HX8K in the CT256 package, clocked by the board's 100 MHz oscillator. Every pin
below comes from the icoBoard's own design files, Clifford Wolf's icotools
(github.com/cliffordwolf/icotools): ``examples/pinout/icoboard.pcf`` (clock and
the four PMOD connectors), ``examples/blinky/icoboard.pcf`` (LEDs), and
``icosoc/icosoc.py`` (the configuration SPI pins, named SPI_FLASH_* there). The
Pi side of the SPI pins is from ``icoprog/icoprog.cc``, which drives them to
load a bitstream. docs/gateware.md has the same map as a wiring table.

The Pi reaches the FPGA over SPI on the FPGA's configuration pins: the same
wires icoprog uses to load a bitstream into the FPGA (RPI_ICE_SELECT low routes
them to the FPGA rather than the flash). So after configuration the Pi talks to
our design on those pins, with the FPGA in the role it had while being
configured: chip select on SS, clock on SCK, the Pi's data into SI (P11), ours
out of SO (P12).

Peripherals go on the PMOD connectors in the layout of Digilent's PMOD type 4
(H-bridge, e.g. the Pmod HB5), one six-pin row ("port") per wheel: pin 1 DIR,
2 EN (the PWM), 3 SA, 4 SB (the wheel's encoder). A 12-pin PMOD has two such
rows (pins 1-4 and 7-10), so the four PMODs give 8 ports: actuator i and sensor
i both use port i, in wire order (`Peripherals`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from amaranth.build import Attrs, Clock, Connector, Pins, Resource, Subsignal
from amaranth.vendor import LatticeICE40Platform

from icefloe.wire.icoboard import Peripherals

PMODS = {
    # connector: pins 1, 2, 3, 4, 7, 8, 9, 10 (icotools examples/pinout/icoboard.pcf)
    1: "D8 B9 B10 B11 B8 A9 A10 A11",
    2: "A5 A2 C3 B4 B7 B6 B3 B5",
    3: "L9 G5 L7 N6 N9 P9 M8 N7",
    4: "T15 T14 T11 R10 R14 T13 T10 T9",
}

PORTS = [(pmod, row) for pmod in (1, 2, 3, 4) for row in ("top", "bottom")]
"""Six-pin ports in order: port i is PMOD (i // 2 + 1), its top row (pins 1-4) or bottom row (7-10)."""

PI_SPI = {
    # signal: (FPGA ball, iCE40 function, Pi header pin, Pi GPIO)
    "sck": ("R11", "SPI_SCK", 7, 4),
    "cs_n": ("R12", "SPI_SS_B", 24, 8),
    "copi": ("P11", "SPI_SI", 29, 5),
    "cipo": ("P12", "SPI_SO", 31, 6),
}
"""The Pi's SPI to the FPGA's configuration pins (icosoc.py pcf; icoprog.cc's RPI_ICE_* lines)."""

CLOCK_PIN = "R9"
LED_PINS = "C8 F7 K9"


@dataclass(frozen=True)
class PinMapRow:
    signal: str
    ball: str
    where: str
    source: str


def port_pins(port: int) -> tuple[str, str, str, str]:
    """FPGA balls of a port's pins 1-4 (DIR, EN, SA, SB)."""
    pmod, row = PORTS[port]
    balls = PMODS[pmod].split()
    return tuple(balls[:4] if row == "top" else balls[4:])  # type: ignore[return-value]


def _port_name(port: int) -> str:
    pmod, row = PORTS[port]
    return f"PMOD{pmod} pins {'1-4' if row == 'top' else '7-10'}"


def pin_map(peripherals: Peripherals | None = None) -> list[PinMapRow]:
    """Every signal of the design for ``peripherals``, with its ball and where the pin comes from."""
    peripherals = peripherals or Peripherals()
    icotools = "icotools examples/pinout/icoboard.pcf"
    rows = [PinMapRow("clk100", CLOCK_PIN, "100 MHz oscillator", icotools)]
    for signal, (ball, function, header, gpio) in PI_SPI.items():
        rows.append(PinMapRow(f"spi {signal}", ball, f"{function}; Pi header pin {header} (GPIO{gpio})",
                              "icotools icosoc.py (SPI_FLASH_*), icoprog.cc (RPI_ICE_*)"))
    for i, led in enumerate(LED_PINS.split()):
        what = ("on while the board runs (START .. EXIT)", "on after a watchdog trip",
                "on while the Pi selects the board")[i]
        rows.append(PinMapRow(f"led{i + 1}", led, what, "icotools examples/blinky/icoboard.pcf"))
    for i in range(len(peripherals.actuators)):
        direction, enable, _, _ = port_pins(i)
        rows.append(PinMapRow(f"motor{i} dir", direction, f"{_port_name(i)}, pin 1 (DIR)", icotools))
        rows.append(PinMapRow(f"motor{i} pwm", enable, f"{_port_name(i)}, pin 2 (EN)", icotools))
    for i in range(len(peripherals.sensors)):
        _, _, a, b = port_pins(i)
        rows.append(PinMapRow(f"encoder{i} a", a, f"{_port_name(i)}, pin 3 (SA)", icotools))
        rows.append(PinMapRow(f"encoder{i} b", b, f"{_port_name(i)}, pin 4 (SB)", icotools))
    return rows


def pin_map_markdown(peripherals: Peripherals | None = None) -> str:
    """`pin_map` as the Markdown table docs/gateware.md shows."""
    lines = ["| signal | FPGA ball | where | from |", "|---|---|---|---|"]
    lines += [f"| {r.signal} | {r.ball} | {r.where} | {r.source} |" for r in pin_map(peripherals)]
    return "\n".join(lines)


class IcoBoardPlatform(LatticeICE40Platform):
    """The icoBoard (iCE40HX8K-CT256, 100 MHz on R9), with the Pi's SPI and the PMOD connectors."""

    device = "iCE40HX8K"
    package = "CT256"
    default_clk = "clk100"
    resources: ClassVar[list[Resource]] = [
        Resource("clk100", 0, Pins(CLOCK_PIN, dir="i"), Clock(100e6),
                 Attrs(GLOBAL=True, IO_STANDARD="SB_LVCMOS")),
        *[Resource("led", i, Pins(pin, dir="o"), Attrs(IO_STANDARD="SB_LVCMOS"))
          for i, pin in enumerate(LED_PINS.split())],
        Resource("pi_spi", 0,
                 Subsignal("sck", Pins(PI_SPI["sck"][0], dir="i")),
                 Subsignal("cs_n", Pins(PI_SPI["cs_n"][0], dir="i")),
                 Subsignal("copi", Pins(PI_SPI["copi"][0], dir="i")),
                 Subsignal("cipo", Pins(PI_SPI["cipo"][0], dir="oe")),
                 Attrs(IO_STANDARD="SB_LVCMOS")),
    ]
    connectors: ClassVar[list[Connector]] = [
        # 12-pin PMOD: signals on 1-4 and 7-10, ground and 3.3 V on 5, 6, 11, 12
        Connector("pmod", n, " ".join([*pins.split()[:4], "-", "-", *pins.split()[4:], "-", "-"]))
        for n, pins in PMODS.items()]

    def __init__(self, peripherals: Peripherals | None = None, **kwargs) -> None:
        super().__init__(**kwargs)
        peripherals = peripherals or Peripherals()
        wheels = []
        for i in range(max(len(peripherals.sensors), len(peripherals.actuators))):
            direction, enable, a, b = port_pins(i)
            subsignals = []
            if i < len(peripherals.actuators):
                subsignals += [Subsignal("dir", Pins(direction, dir="o")), Subsignal("pwm", Pins(enable, dir="o"))]
            if i < len(peripherals.sensors):  # pulled up: encoders often have open-collector outputs
                subsignals += [Subsignal("a", Pins(a, dir="i"), Attrs(PULLUP=1)),
                               Subsignal("b", Pins(b, dir="i"), Attrs(PULLUP=1))]
            wheels.append(Resource("wheel", i, *subsignals, Attrs(IO_STANDARD="SB_LVCMOS")))
        self.add_resources(wheels)
