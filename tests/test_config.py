"""Robot config files: defaults, `extends`, placeholders, and errors that name the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from icefloe import config, paths
from icefloe.errors import ConfigError


def write(tmp_path: Path, text: str, name: str = "robot.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_embedded_default_is_a_simulated_penguinpi_named_sim() -> None:
    cfg = config.load()
    assert (cfg.name, cfg.board.kind, cfg.board.backend) == ("sim", "penguinpi", "sim")
    assert cfg.zenoh.listen == ["tcp/0.0.0.0:7447"]
    assert cfg.board.serial_port == str(cfg.runtime_dir / "ttyPPI")


def test_every_shipped_robot_config_loads() -> None:
    shipped = sorted(paths.packaged("robots").glob("*.toml"))
    assert {p.stem for p in shipped} >= {"sim", "sim-icoboard", "penguin1"}
    for path in shipped:
        assert config.load(path).name


def test_a_name_is_a_name_from_any_folder_and_a_path_is_a_path(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("ICEFLOE_CONFIG_DIR", str(tmp_path / "nobody"))
    (tmp_path / "sim").mkdir()  # a folder named like the robot, as the checkout's sim/ is
    monkeypatch.chdir(tmp_path)
    assert config.load("sim").name == "sim"
    assert config.find("sim") == paths.packaged("robots", "sim.toml")
    with pytest.raises(ConfigError, match=r"^\./sim: is a folder, not a robot config"):
        config.load("./sim")
    with pytest.raises(ConfigError, match=r"^sim\.toml: no such robot config \(for the shipped robot config 'sim', "
                                          r"give its name without \.toml\)"):
        config.load("sim.toml")
    with pytest.raises(ConfigError, match=r"^nosuch: no robot config of that name \(known: penguin1, sim, "):
        config.load("nosuch")
    with pytest.raises(ConfigError, match="not a robot config name"):
        config.load("bad name!")


def test_your_own_configs_override_the_shipped_ones_by_name(tmp_path: Path, monkeypatch) -> None:
    robots = tmp_path / "mine" / "robots"
    robots.mkdir(parents=True)
    (robots / "sim.toml").write_text('extends = "sim"\n[hwbridge]\ndeadman_s = 0.25\n')  # the shipped sim
    (robots / "r2d2.toml").write_text('extends = "sim.toml"\nname = "r2d2"\n')  # extends your own sim
    monkeypatch.setenv("ICEFLOE_CONFIG_DIR", str(tmp_path / "mine"))
    assert config.load("sim").hwbridge.deadman_s == 0.25
    r2d2 = config.load("r2d2")
    assert (r2d2.name, r2d2.hwbridge.deadman_s) == ("r2d2", 0.25)
    assert "r2d2" in paths.known("robots")


def test_extends_merges_tables(tmp_path: Path) -> None:
    base = write(tmp_path, 'name = "base"\n[hwbridge]\nrate_hz = 500.0\ndeadman_s = 0.3\n', "base.toml")
    p = write(tmp_path, f'extends = "{base.name}"\nname = "r2"\nrun_dir = "/x"\n[hwbridge]\nrate_hz = 250.0\n')
    cfg = config.load(p)
    assert (cfg.name, cfg.hwbridge.rate_hz, cfg.hwbridge.deadman_s) == ("r2", 250.0, 0.3)
    assert cfg.board.sim_socket == "/x/icoboard.sock"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('[hwbridge]\nrate_hz = "fast"\n', "hwbridge.rate_hz: Expected `float`, got `str`"),
        ("[hwbridge]\nrat_hz = 1.0\n", "[hwbridge]: Object contains unknown field `rat_hz`"),
        ('[board]\nkind = "arduino"\n', "board.kind: Invalid enum value 'arduino'"),
        ("name = \n", "not valid TOML"),
        ('name = "a/b"\n', "name: 'a/b' is not a usable robot name"),
        ('extends = "missing.toml"\n', "missing.toml nor missing: no robot config of that name"),
    ],
)
def test_bad_files_name_the_file_and_key(tmp_path: Path, text: str, message: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        config.load(p)
    assert message in str(err.value)
    assert "robot.toml" in str(err.value) or "missing.toml" in str(err.value)


def test_extends_loop_is_an_error(tmp_path: Path) -> None:
    write(tmp_path, 'extends = "b.toml"\n', "a.toml")
    write(tmp_path, 'extends = "a.toml"\n', "b.toml")
    with pytest.raises(ConfigError, match="loops back"):
        config.load(tmp_path / "a.toml")


@pytest.mark.parametrize(("toml", "named"), [
    ("[hwbridge]\ndeadman_s = -1", "hwbridge.deadman_s: Expected `float` > 0.0"),
    ("[hwbridge]\ndeadman_s = inf", "hwbridge.deadman_s: Expected `float` <= 86400.0"),
    ("[hwbridge]\nrate_hz = 0.0", "hwbridge.rate_hz: Expected `float` > 0.0"),
    ("[hwbridge]\nrate_hz = 50_000.0", "hwbridge.rate_hz: Expected `float` <= 10000.0"),
    ("[hwbridge]\nwheels_rate_hz = -1.0", "hwbridge.wheels_rate_hz: Expected `float` >= 0.0"),
    ("[hwbridge]\nrest_rate_hz = 10.0", "hwbridge: `rest_rate_hz` must be 0 (never rest) or at least 25 Hz, got 10: "
     "the icoBoard's watchdog stops the wheels after 50 ms without a frame"),
    ("[hwbridge]\nrest_after_s = 0.0", "hwbridge.rest_after_s: Expected `float` >= 0.1"),
    ("[hwbridge]\nkp = nan", "hwbridge.kp: Expected `float` >= 0.0"),
    ("[hwbridge]\npriority = 100", "hwbridge.priority: Expected `int` <= 99"),
    ("[geometry]\nticks_per_rev = 0", "geometry.ticks_per_rev: Expected `int` >= 1"),
    ("[geometry]\ntrack = -0.1", "geometry.track: Expected `float` > 0.0"),
    ("[odometry]\nrate_hz = 0", "odometry.rate_hz: Expected `float` > 0.0"),
    ("[localizer]\nsigma_bearing = 0.0", "localizer.sigma_bearing: Expected `float` > 0.0"),
    ("[localizer]\ninitial_x = inf", "localizer: `initial_x` must be a finite number, got inf"),
    ("[power]\ncritical_v = 7.5", "power: critical_v (7.5 V) must be below low_v (7.0 V)"),
    ("[power]\npole = 1.0", "power.pole: Expected `float` < 1.0"),
    ("[power]\npoweroff_command = []", "power.poweroff_command: Expected `array` of length >= 1"),
    ("[display]\nrate_hz = 1000", "display.rate_hz: Expected `float` <= 100.0"),
    ("[sim]\ntruth_rate_hz = -5", "sim.truth_rate_hz: Expected `float` > 0.0"),
    ("[webapi]\nport = 70000", "webapi.port: Expected `int` <= 65535"),
    ("[camera]\njpeg_quality = 101", "camera.jpeg_quality: Expected `int` <= 100"),
    ("[camera]\nwidth = 0", "camera.width: Expected `int` >= 64"),
    ("[camera]\nheight = 100_000", "camera.height: Expected `int` <= 4096"),
    ("[camera]\nfps = 1000.0", "camera.fps: Expected `float` <= 120.0"),
    ("[camera]\ndetection_rate_hz = -1.0", "camera.detection_rate_hz: Expected `float` >= 0.0"),
    ("[camera]\ndetection_rate_hz = nan", "camera.detection_rate_hz: Expected `float` >= 0.0"),
    ("[camera]\nfps = 10.0\ndetection_rate_hz = 15.0",
     "camera: detection_rate_hz (15) must be at most fps (10): detection cannot search frames that were never "
     "captured"),
    ("[camera]\nwidth = 160\nheight = 120",
     "camera: image_width x image_height (320x240) must fit in width x height (160x120): the images are the "
     "frames made smaller"),
])
def test_a_value_out_of_range_is_refused_naming_the_key(tmp_path: Path, toml: str, named: str) -> None:
    path = write(tmp_path, f'extends = "sim"\n{toml}\n')
    with pytest.raises(ConfigError) as refused:
        config.load(path)
    assert str(refused.value) == f"{path}: {named}"


def test_a_relative_calibration_file_is_beside_the_config_that_names_it(tmp_path: Path) -> None:
    """A robot config that names ``cam.yaml`` means the file beside it, whichever file extends it and from
    whatever folder it is loaded; an absolute path and a placeholder are left as they are."""
    (tmp_path / "base").mkdir()
    write(tmp_path / "base", '[camera]\ncalibration = "cam.yaml"\n[overhead]\ncalibration = "/abs/over.yaml"\n',
          "base.toml")
    mine = write(tmp_path, f'extends = "{tmp_path / "base" / "base.toml"}"\nname = "mine"\n')
    cfg = config.load(mine)
    assert cfg.camera.calibration == str(tmp_path / "base" / "cam.yaml")
    assert cfg.overhead.calibration == "/abs/over.yaml"
    own = write(tmp_path, '[camera]\ncalibration = "{run_dir}/cam.yaml"\n', "own.toml")
    assert config.load(own).camera.calibration.endswith("/cam.yaml") and "{" not in config.load(own).camera.calibration
