"""power: battery monitor and shutdown manager.

Watches the battery (``hw/battery`` -> ``power/battery``), the shutdown button,
the board's shutdown-request line and the ``power/request`` query, and shuts
the robot down in a fixed order. See ``docs/power-oled.md``.

Modules: `battery` (filter and thresholds, pure), `lines` (debounce and hold,
pure), `gpio` (the GPIO backends), `shutdown` (the sequence), `__main__` (the
service).
"""
