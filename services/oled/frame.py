"""A 128×32 1-bit frame: text drawing, inversion, packing for the bus and PBM files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import font

WIDTH = 128
"""Pixels."""
HEIGHT = 32
"""Pixels."""
COLS = WIDTH // font.WIDTH
"""Characters per row: 21."""
ROWS = HEIGHT // font.HEIGHT
"""Text rows: 4."""


class Frame:
    """The pixels of the screen, ``pixels[y, x]`` in {0, 1}, 1 = lit."""

    def __init__(self, pixels: np.ndarray | None = None) -> None:
        if pixels is None:
            pixels = np.zeros((HEIGHT, WIDTH), dtype=np.uint8)
        if pixels.shape != (HEIGHT, WIDTH):
            raise ValueError(f"a frame is {HEIGHT}×{WIDTH} pixels, got {pixels.shape}")
        self.pixels = pixels.astype(np.uint8)

    def text(self, row: int, col: int, text: str, *, invert: bool = False) -> None:
        """Draw ``text`` from character cell (row, col); what does not fit is cut off."""
        y = row * font.HEIGHT
        for i, ch in enumerate(text[: max(0, COLS - col)]):
            x = (col + i) * font.WIDTH
            cell = font.cell(ch)
            self.pixels[y : y + font.HEIGHT, x : x + font.WIDTH] = 1 - cell if invert else cell

    def title(self, text: str, right: str = "") -> None:
        """Row 0 as a title bar: lit background, dark text, ``right`` aligned to the right edge."""
        self.pixels[0 : font.HEIGHT, :] = 1
        self.text(0, 0, text[:COLS], invert=True)
        if right:
            self.text(0, COLS - len(right), right, invert=True)

    def bar(self, row: int, fraction: float) -> None:
        """A horizontal gauge filling ``fraction`` (0..1) of text row ``row``."""
        y0, y1 = row * font.HEIGHT + 1, row * font.HEIGHT + font.HEIGHT - 1
        self.pixels[y0, :] = self.pixels[y1 - 1, :] = 1  # outline
        self.pixels[y0:y1, 0] = self.pixels[y0:y1, WIDTH - 1] = 1
        fill = round(min(max(fraction, 0.0), 1.0) * (WIDTH - 4))
        self.pixels[y0 + 2 : y1 - 2, 2 : 2 + fill] = 1

    def inverted(self) -> Frame:
        return Frame(1 - self.pixels)

    def pack(self) -> bytes:
        """1 bit per pixel, row-major, most significant bit first (the ``oled/frame`` layout)."""
        return np.packbits(self.pixels, axis=None, bitorder="big").tobytes()

    @classmethod
    def unpack(cls, data: bytes) -> Frame:
        if len(data) != WIDTH * HEIGHT // 8:
            raise ValueError(f"a packed frame is {WIDTH * HEIGHT // 8} bytes, got {len(data)}")
        bits = np.unpackbits(np.frombuffer(data, dtype=np.uint8), bitorder="big")
        return cls(bits.reshape(HEIGHT, WIDTH))

    # PBM (P4) stores 1 = black. We store lit pixels as white, so an image viewer
    # shows the golden files the way the OLED looks: light text on a dark screen.
    def to_pbm(self) -> bytes:
        return f"P4\n{WIDTH} {HEIGHT}\n".encode() + Frame(1 - self.pixels).pack()

    @classmethod
    def from_pbm(cls, data: bytes) -> Frame:
        header = f"P4\n{WIDTH} {HEIGHT}\n".encode()
        if not data.startswith(header):
            raise ValueError(f"not a {WIDTH}×{HEIGHT} binary PBM (P4) file")
        return cls.unpack(data[len(header) :]).inverted()

    def save_pbm(self, path: Path) -> None:
        path.write_bytes(self.to_pbm())

    def ascii(self) -> str:
        """The frame as text, ``#`` lit, ``.`` dark (for test failure messages)."""
        return "\n".join("".join("#" if p else "." for p in row) for row in self.pixels)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Frame) and bool(np.array_equal(self.pixels, other.pixels))

    __hash__ = None  # type: ignore[assignment]  # mutable
