"""Where frames go, chosen by ``display.kind``; the service cannot tell them apart.

* ``ssd1306``: our frames on an SSD1306 128×32 over I2C through ``luma.oled``
  (``pip install luma.oled``; imported only when chosen).
* ``penguinpi``: the PenguinPi firmware drives the HAT's OLED itself, with its
  own screens. We select the matching firmware screen (``io/screen``) and forward
  user text (``io/text``); hwbridge passes both to the board.
* ``none``: nothing (a robot without a display).

Whatever the sink, the service also publishes every frame on ``oled/frame``.
"""

from __future__ import annotations

import asyncio
from typing import Any, Protocol

from icefloe.config import Display
from icefloe.runtime import Node
from icefloe.schemas import keys
from icefloe.schemas import messages as m

from .font import CHARSET
from .frame import HEIGHT, WIDTH, Frame
from .screens import SCREENS

FIRMWARE_SCREENS = {"network": 0, "user": 1, "battery": 2, "encoders": 3, "motors": 4,
                    "services": 5, "timing": 6, "errors": 7, "pose": 9}
"""Our screen -> the PenguinPi firmware's screen number (penguinpi-facts §3.11).
The firmware has no pose screen (9 is blank); "services" shows its PERFORMANCE page."""


class Sink(Protocol):
    async def show(self, frame: Frame, screen: int) -> None:
        """Show ``frame``, the rendering of screen number ``screen``."""
        ...

    def user_text(self, text: str) -> None:
        """New user text arrived (for sinks that keep their own text screen)."""
        ...

    def close(self) -> None: ...


class NoSink:
    async def show(self, frame: Frame, screen: int) -> None:
        pass

    def user_text(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass


class Ssd1306Sink:
    """An SSD1306 128×32 on the Pi's I2C bus, through luma.oled."""

    def __init__(self, port: int, address: int) -> None:
        try:
            from luma.core.interface.serial import i2c
            from luma.oled.device import ssd1306
            from PIL import Image
        except ImportError:
            raise RuntimeError("display.kind = \"ssd1306\" needs luma.oled (pip install luma.oled)") from None
        self._image = Image
        self._device: Any = ssd1306(i2c(port=port, address=address), width=WIDTH, height=HEIGHT)

    async def show(self, frame: Frame, screen: int) -> None:
        # PIL's mode "1" raw layout is ours: rows of MSB-first bits, 1 = white (lit).
        image = self._image.frombytes("1", (WIDTH, HEIGHT), frame.pack())
        await asyncio.to_thread(self._device.display, image)  # I2C writes block for ~ms

    def user_text(self, text: str) -> None:
        pass

    def close(self) -> None:
        self._device.cleanup()


def firmware_text(text: str) -> str:
    """Text the PenguinPi firmware can show: ASCII glyphs, ``\\n`` and ``\\f``; the rest -> ``?``."""
    return "".join(c if c in CHARSET or c in "\n\f" else "?" for c in text)


class PenguinPiSink:
    """The PenguinPi firmware's own display: select its screen, forward user text."""

    def __init__(self, node: Node) -> None:
        self._screen_pub = node.publisher(keys.BOARD_SCREEN)
        self._text_pub = node.publisher(keys.BOARD_TEXT)
        self._shown: int | None = None

    async def show(self, frame: Frame, screen: int) -> None:
        if screen != self._shown:  # the firmware keeps its screen: send changes only
            self._screen_pub.put(m.OledScreen(index=FIRMWARE_SCREENS[SCREENS[screen].name]))
            self._shown = screen

    def user_text(self, text: str) -> None:
        self._text_pub.put(m.OledText(text=firmware_text(text)))

    def close(self) -> None:
        pass


def open_sink(node: Node, display: Display) -> Sink:
    if display.kind == "ssd1306":
        return Ssd1306Sink(display.i2c_port, display.i2c_address)
    if display.kind == "penguinpi":
        return PenguinPiSink(node)
    return NoSink()
