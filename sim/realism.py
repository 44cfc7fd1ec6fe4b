"""How unkind the simulated robot is: each effect a config key, its value in both profiles, and its source.

``[sim] profile`` picks the defaults; any key of ``[sim.wheels]``, ``[sim.lens]``, ``[sim.image]``
(or ``sim.slip``, ``sim.encoder_noise``) set in a robot config wins over its profile:

* **realistic** (``[sim] profile = "realistic"``, the default): a PenguinPi as it is, not as drawn.
  Its wheels differ from each other and from ``[geometry]``, they slip when the robot starts, stops
  and turns; its camera has a lens to calibrate, auto exposure in an unevenly lit room (so motion
  blur, and noise in the dark), JPEG artefacts, and frames that arrive late, a few not at all.
* **ideal** (``[sim] profile = "ideal"``): the robot is exactly what its config says it is:
  ``[geometry]``'s wheels, the lens the camera service believes (its calibration file, or the
  nominal ``focal_px``), the camera's noise and flicker of before this table existed: the simulator
  as it was, for debugging, and for tests about something other than realism.

`EFFECTS` is the table (docs/sim.md shows it, and a test keeps the two the same); `wheels` and
`picture` resolve a config's values. Every random effect draws from ``sim.seed``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from icefloe.config import RobotConfig

NOMINAL = "nominal"
"""An ideal value meaning "what the robot's config believes" (``[geometry]``, the camera's lens)."""


@dataclass(frozen=True)
class Effect:
    """One effect: its config key, its value in each profile, its unit and where the value comes from."""

    key: str
    """Below ``[sim]``, e.g. "wheels.track"."""
    ideal: Any
    realistic: Any
    unit: str
    source: str


PENGUINPI_DIAMETER = 0.065
"""The PenguinPi's wheel as drawn, m (the report's 65 mm wheel; ``[geometry] wheel_diameter``)."""

EFFECTS: tuple[Effect, ...] = (
    Effect("wheels.diameter_left", NOMINAL, 0.0642, "m",
           "assumed, to be measured on a robot: the 65 mm wheel rolls 1.5 % "
           "smaller under the robot's weight, and the two wheels of a moulded pair differ by 0.6 %"),
    Effect("wheels.diameter_right", NOMINAL, 0.0638, "m", "as diameter_left"),
    Effect("wheels.track", NOMINAL, 0.1535, "m",
           "the baseline the ECE4078 course ships for its PenguinPis (calibration/param/baseline.txt), "
           "against the drawing's 0.156 m"),
    Effect("wheels.slip_accel", 0.0, 0.03, "s²/m",
           "assumed, to be measured on a robot: 3 % of a wheel's travel lost per m/s² of its "
           "acceleration, so a start at the hwbridge's 2 m/s² loses 6 % of it"),
    Effect("wheels.slip_turn", 0.0, 0.02, "s/rad",
           "assumed, to be measured on a robot: the wheels scrub sideways in a turn, 2 % of the turn "
           "lost per rad/s (3 % at the follower's 1.5 rad/s)"),
    Effect("wheels.dead_band_left", 9.0, 11.0, "% PWM",
           "the PenguinPi report (§3.2.2) measured 9 % on motor A (the right); the left motor assumed "
           "2 points stiffer, so starts pull to one side"),
    Effect("wheels.dead_band_right", 9.0, 9.0, "% PWM", "the PenguinPi report, §3.2.2 (motor A)"),
    Effect("wheels.battery_sag", True, True, "",
           "a DC motor's speed follows its voltage; the report's slope was measured at the pack's 7.4 V"),
    Effect("slip", 0.0, 0.05, "",
           "assumed: random slip per 1 ms step, as bench/slam.py and tests/test_slam_sim.py drove before"),
    Effect("encoder_noise", 0.0, 0.01, "", "assumed, as slip"),
    Effect("lens.fx", NOMINAL, 540.0, "px",
           "the Pi Camera v2's 3.04 mm lens over 1.12 µm pixels, binned 2x2 and scaled to 640x480: "
           "530 px; this unit 2 % long (lenses vary); `icefloe calibrate` measures it"),
    Effect("lens.fy", NOMINAL, 536.0, "px", "as fx, pixels 0.7 % from square (assumed)"),
    Effect("lens.cx", NOMINAL, 327.0, "px", "assumed: the lens 7 px off the sensor's centre"),
    Effect("lens.cy", NOMINAL, 244.0, "px", "assumed: 4 px off"),
    Effect("lens.distortion", NOMINAL, (-0.15, 0.09, 0.0008, -0.0012, 0.0), "",
           "k1, k2, p1, p2, k3: barrel distortion of the order published Pi camera calibrations find, "
           "a lens a little tilted (assumed, to be measured: `icefloe calibrate`)"),
    Effect("image.exposure_s", 0.0, 0.015, "s",
           "assumed, to be measured (picamera2's ExposureTime and AnalogueGain metadata): a lit lab "
           "needs 15 ms at unit gain, which the Raspberry Pi camera's normal exposure mode buys as a "
           "10 ms shutter and a gain of 1.5 (sim/sensor.py, AE_STEPS)"),
    Effect("image.light_variation", 0.0, 0.35, "",
           "assumed, to be measured with the camera's own exposure: ceiling panels over a 4 m room, the "
           "darkest corner 35 % dimmer than under a lamp"),
    Effect("image.flicker", 0.15, 0.03, "",
           "ideal: the simulator as before; realistic: mains flicker left after the camera's "
           "anti-flicker (assumed)"),
    Effect("image.noise", 3.0, 2.0, "grey levels",
           "assumed: sensor noise after the camera's denoising at unit gain; it grows with the gain "
           "auto exposure needs in the dark"),
    Effect("image.blur_px", 0.0, 0.6, "px", "assumed: the lens's own softness at 640x480"),
    Effect("image.jpeg_quality", 0, 85, "",
           "the PenguinPi's own MJPEG stream (ppweb.py), which course code detects markers on; "
           "icefloe's picamera2 source reads uncompressed frames, so this is the unkinder case"),
    Effect("image.latency_s", 0.0, 0.05, "s",
           "assumed, to be measured: picamera2 hands a frame over one to two frame periods after its "
           "exposure; the frame is stamped when it arrives, as icefloe's sources stamp it"),
    Effect("image.latency_jitter_s", 0.0, 0.01, "s", "assumed, to be measured"),
    Effect("image.drop_rate", 0.0, 0.01, "", "assumed: a frame in a hundred lost in the pipeline"),
)
"""Every effect of the simulated robot, in the order of docs/sim.md's table."""

_BY_KEY = {e.key: e for e in EFFECTS}


def value(config: RobotConfig, key: str) -> Any:
    """The value of effect ``key`` for ``config``: its own setting, else its profile's (`NOMINAL` for
    "what the config believes", which the caller resolves)."""
    section: Any = config.sim
    *tables, name = key.split(".")
    for table in tables:
        section = getattr(section, table)
    own = getattr(section, name)
    if own is not None:
        return own
    effect = _BY_KEY[key]
    return effect.ideal if config.sim.profile == "ideal" else effect.realistic


@dataclass(frozen=True)
class Wheels:
    """The simulated robot's true wheels and motors (`sim.world.World`), resolved."""

    diameter_left: float
    """m."""
    diameter_right: float
    track: float
    """m."""
    slip_accel: float = 0.0
    slip_turn: float = 0.0
    dead_band_left: float = 9.0
    """% PWM (the report's 9 %: `sim.world.DEAD_BAND_PCT`)."""
    dead_band_right: float = 9.0
    battery_sag: bool = True
    slip: float = 0.0
    encoder_noise: float = 0.0


def wheels(config: RobotConfig) -> Wheels:
    """``config``'s true wheels: its ``[sim.wheels]``, else its profile's (ideal: ``[geometry]``)."""
    g = config.geometry

    def get(key: str, nominal: float) -> Any:
        v = value(config, key)
        return nominal if v == NOMINAL else v

    return Wheels(
        diameter_left=get("wheels.diameter_left", g.wheel_diameter),
        diameter_right=get("wheels.diameter_right", g.wheel_diameter),
        track=get("wheels.track", g.track),
        slip_accel=value(config, "wheels.slip_accel"), slip_turn=value(config, "wheels.slip_turn"),
        dead_band_left=value(config, "wheels.dead_band_left"), dead_band_right=value(config, "wheels.dead_band_right"),
        battery_sag=value(config, "wheels.battery_sag"),
        slip=value(config, "slip"), encoder_noise=value(config, "encoder_noise"),
    )


@dataclass(frozen=True)
class Picture:
    """What the simulated camera's sensor and pipeline do to a frame (`sim.camera`, the camera's
    `SimSource`), resolved. The defaults are the ideal profile's: the renderer as it was."""

    exposure_s: float = 0.0
    light_variation: float = 0.0
    flicker: float = 0.15
    noise: float = 3.0
    blur_px: float = 0.0
    jpeg_quality: int = 0
    latency_s: float = 0.0
    latency_jitter_s: float = 0.0
    drop_rate: float = 0.0

    @property
    def plain(self) -> bool:
        """Nothing but the noise, flicker and blur of the renderer as it was (the ideal profile)."""
        return not (self.exposure_s or self.light_variation or self.jpeg_quality)


def picture(config: RobotConfig) -> Picture:
    """``config``'s camera effects: its ``[sim.image]``, else its profile's."""
    return Picture(**{name: value(config, f"image.{name}") for name in Picture.__dataclass_fields__})


def lens(config: RobotConfig) -> dict[str, Any]:
    """``config``'s true lens, key by key (fx, fy, cx, cy, distortion): its ``[sim.lens]``, else its
    profile's; `NOMINAL` where the lens is the one the camera service believes."""
    return {name: value(config, f"lens.{name}") for name in ("fx", "fy", "cx", "cy", "distortion")}
