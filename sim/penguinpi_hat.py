"""The PenguinPi HAT (ID 1) and OLED state, as the firmware keeps them (facts §3.10-3.11).

Part of the firmware model (``penguinpi_firmware.py``): the DIP switch, the four
buttons S1..S4, the 16-LED array, the IP/MAC lines, the selected OLED screen,
the error text and the user-text buffer (bytes received outside datagrams).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from icefloe.wire import penguinpi as w

if TYPE_CHECKING:
    from .penguinpi_firmware import PenguinPiFirmware

SCREENS = ("IP_ADDR", "USER", "BATTERY", "ENCODERS", "PID", "PERFORMANCE", "TIMING", "ERROR",
           "DATAGRAM", "END", "SHUTDOWN")
"""OLED screens by index (facts §3.11); 11..255 are blank."""
S1_NEXT_SCREEN, S2_ALL_STOP, S3_SCREEN_ACTION, S4_COUNT = 0, 1, 2, 3
"""Button bits in the HAT's input port."""
BUTTONS = {"S1": S1_NEXT_SCREEN, "S2": S2_ALL_STOP, "S3": S3_SCREEN_ACTION, "S4": S4_COUNT}
BEACON_PATTERN = 0x9008
"""LED-array word written on every HAT interrupt while DIP SW3 (beacon) is on."""
USER_LINES, USER_WIDTH = 4, 20
USER_RESET = ("USER TEXT", "", "", "")


class Hat:
    """HAT and OLED state. Called with the firmware's lock held."""

    def __init__(self, firmware: PenguinPiFirmware, dip: int) -> None:
        if not 0 <= dip <= 15:
            raise ValueError(f"dip must be 0..15, got {dip}")
        self.fw = firmware
        self.dip = dip
        """DIP switches: SW1 = 8, SW2 = 4, SW3 = 2 (beacon), SW4 = 1 (PI control)."""
        self.held = 0
        """Buttons held now, bit n = S(n+1)."""
        self.interrupt_seen = False
        self.beacon = False
        self.button_count = 0
        """S4 presses since the last HAT_GET_BUTTON (uint8)."""
        self.ledarray = 0
        """Last HAT_SET_LEDARRAY value (what HAT_GET_LEDARRAY returns)."""
        self.ledarray_out = 0
        """What the LED-array expander shows (clobbered by the beacon rewrite)."""
        self.ip_eth: tuple[int, ...] = (0, 0, 0, 0)
        self.ip_wlan: tuple[int, ...] = (0, 0, 0, 0)
        self.mac_wlan: tuple[int, ...] = (0, 0, 0, 0, 0, 0)
        self.screen = 0
        self.inverted = False
        """OLED inverted by the low-battery check (never reverted)."""
        self.error_text = ""
        self.user_lines = list(USER_RESET)
        self._scroll = False

    # ------------------------------------------------------------------ datagrams

    def datagram(self, op: int, payload: bytes) -> bytes | None:
        """HAT opcodes (facts §2.6); lengths were checked by the caller."""
        H = w.HatOp
        if op == H.HAT_SET_IP_ETH:
            self.ip_eth = tuple(payload)
        elif op == H.HAT_SET_IP_WLAN:
            self.ip_wlan = tuple(payload)
        elif op == H.HAT_SET_MAC_WLAN:
            self.mac_wlan = tuple(payload)
        elif op == H.HAT_SET_SCREEN:
            self.screen = payload[0]                   # no range check, as the firmware
        elif op == H.HAT_SET_LEDARRAY:
            self.ledarray = self.ledarray_out = w.unpack_uint16(payload)
        elif op == H.HAT_GET_DIP:
            unshifted = not self.interrupt_seen and self.fw.defects.dip_unshifted_at_boot
            return bytes(((self.dip << 4 if unshifted else self.dip) & 0xFF,))
        elif op == H.HAT_GET_BUTTON:
            count, self.button_count = self.button_count, 0
            return bytes((count,))
        elif op == H.HAT_GET_LEDARRAY:
            return w.pack_uint16(self.ledarray)
        return None

    # ------------------------------------------------------------------ test handles

    def set_dip(self, value: int) -> None:
        """Flip the DIP switches to ``value`` (0..15); a change raises a HAT interrupt."""
        if not 0 <= value <= 15:
            raise ValueError(f"dip must be 0..15, got {value}")
        with self.fw.lock:
            changed = value != self.dip
            self.dip = value
            if changed:
                self._interrupt()

    def hold(self, button: str, down: bool) -> None:
        """Press (``down=True``) or release a button "S1".."S4"; each change is an interrupt."""
        if button not in BUTTONS:
            raise ValueError(f"button must be one of S1..S4, got {button!r}")
        with self.fw.lock:
            bit = 1 << BUTTONS[button]
            self.held = self.held | bit if down else self.held & ~bit
            self._interrupt()

    def press(self, button: str) -> None:
        """Press and release a button."""
        self.hold(button, True)
        self.hold(button, False)

    def _interrupt(self) -> None:
        """What the firmware does on every HAT interrupt (facts §3.10)."""
        fw = self.fw
        self.interrupt_seen = True
        fw.pid_on = bool(self.dip & 0b0001)
        self.beacon = bool(self.dip & 0b0010)
        if self.held & (1 << S1_NEXT_SCREEN):
            self.screen = self.screen + 1 if self.screen + 1 < 9 else 0
        if self.held & (1 << S2_ALL_STOP):
            fw.left.demand = fw.right.demand = 0
        if self.held & (1 << S3_SCREEN_ACTION):
            name = SCREENS[self.screen] if self.screen < len(SCREENS) else ""
            if name == "ENCODERS":
                fw.zero_encoders()
            elif name == "PID":
                fw.right.demand, fw.left.demand = 30, -30
            elif name == "ERROR":
                self.error_text = ""
            elif name == "USER":
                self.reset_user_text()
        if self.held & (1 << S4_COUNT):
            self.button_count = (self.button_count + 1) & 0xFF
        self.ledarray_out = BEACON_PATTERN if self.beacon else 0

    # ------------------------------------------------------------------ user text

    def user_byte(self, byte: int) -> None:
        """A byte received outside a datagram: OLED user text (facts §3.11)."""
        if byte == 0x0A:
            self._scroll = True
        elif byte == 0x0C:
            self.user_lines = list(USER_RESET)     # the scroll flag is not cleared (sic)
        else:
            if self._scroll or len(self.user_lines[3]) >= USER_WIDTH:
                self.user_lines = [*self.user_lines[1:], ""]
                self._scroll = False
            self.user_lines[3] += chr(byte)         # \r, \t, >= 0x80 stored as they are

    def reset_user_text(self) -> None:
        self.user_lines = list(USER_RESET)
        self._scroll = False

    @property
    def screen_name(self) -> str:
        """Name of the selected OLED screen ("" for the blank ones)."""
        return SCREENS[self.screen] if self.screen < len(SCREENS) else ""
