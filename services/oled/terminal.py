"""The user text screen: a tiny 21×4 terminal fed by ``oled/text``.

Like the PenguinPi firmware's user screen, with its rough edges filed off:

* ``\\n`` starts a new line (scrolling up when the screen is full),
* ``\\f`` clears the screen,
* ``\\r`` starts the current line again (clears it), ``\\t`` advances to the next multiple of 4,
* long lines wrap at 21 characters,
* accented letters lose their accents (é -> e); other characters without a
  glyph, and other control characters, show as a hollow box, so a student sees
  that something was sent.
"""

from __future__ import annotations

import unicodedata

from .font import CHARSET
from .frame import COLS, ROWS

MAX_TEXT = 1024
"""Longest accepted ``oled/text`` message, characters; longer ones are dropped with a log line."""

BOX = "\ufffd"
"""Stands for a character that cannot be shown (the font draws it as a hollow box)."""


def printable(ch: str) -> str:
    """``ch`` if the font has it, its unaccented letter if that has a glyph, else `BOX`."""
    if ch in CHARSET:
        return ch
    base = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
    return base if len(base) == 1 and base in CHARSET else BOX


class Terminal:
    """Lines of text that scroll up, ``ROWS`` lines of ``COLS`` characters."""

    def __init__(self, rows: int = ROWS, cols: int = COLS) -> None:
        self.rows, self.cols = rows, cols
        self.lines: list[str] = [""] * rows
        self._row = 0  # the line being written
        self.replaced = 0
        """Characters shown as a box since start (the service logs it)."""

    def clear(self) -> None:
        self.lines, self._row = [""] * self.rows, 0

    def _newline(self) -> None:
        if self._row < self.rows - 1:
            self._row += 1
        else:
            self.lines = [*self.lines[1:], ""]

    def _put(self, ch: str) -> None:
        if len(self.lines[self._row]) >= self.cols:
            self._newline()
        self.lines[self._row] += ch

    def write(self, text: str) -> None:
        """Append ``text``; see the module docstring for the control characters."""
        for ch in text:
            if ch == "\n":
                self._newline()
            elif ch == "\f":
                self.clear()
            elif ch == "\r":
                self.lines[self._row] = ""
            elif ch == "\t":
                self._put(" ")
                while len(self.lines[self._row]) % 4 and len(self.lines[self._row]) < self.cols:
                    self._put(" ")
            else:
                shown = printable(ch)
                self.replaced += shown == BOX
                self._put(shown)
