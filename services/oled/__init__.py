"""oled: the screen manager of the robot's 128×32 monochrome display.

Renders screens (network, user text, battery, encoders, motors, loop timing,
services, errors, pose) into a 1-bit frame, publishes it on ``oled/frame``
and shows it on a sink: an SSD1306 over I2C, the PenguinPi firmware's own
screens, or nothing. See ``docs/power-oled.md``.

Modules: `font` (6×8 glyphs as data), `frame` (the bitmap), `terminal` (the
user text screen), `screens` (pure rendering), `sinks` (where frames go),
`__main__` (the service).
"""
