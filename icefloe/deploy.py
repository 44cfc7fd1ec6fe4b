"""Install (or remove) an icefloe robot on its Raspberry Pi: what `deploy/up.sh` does on a robot.

    python -m icefloe.deploy install CONFIG [--dry-run]     (deploy/up.sh on a Pi)
    python -m icefloe.deploy remove CONFIG [--dry-run]      (deploy/down.sh)

Every step is an `Action`: a description, and either a command or a file to
write. ``--dry-run`` prints them all and changes nothing. The steps are
idempotent: files are rewritten with the same content, users and groups are
created only when missing, systemd is told to reload.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from . import config as config_mod
from . import paths
from .config import RobotConfig

SYSTEMD_TEMPLATES = paths.packaged("systemd")
UNIT_DIR = Path("/etc/systemd/system")
USER = "icefloe"
GROUPS = ("dialout", "spi", "i2c", "gpio", "video")
BOOT_CONFIG = Path("/boot/firmware/config.txt")
BOOT_LINES = (
    "enable_uart=1",          # the PenguinPi's serial link on GPIO14/15
    "dtoverlay=disable-bt",   # ... on the full PL011 UART, not the mini-UART that follows the CPU clock
    "dtparam=spi=on",         # the icoBoard
    "dtparam=i2c_arm=on",     # the OLED and battery monitors
)
UDEV_RULES = """\
# icefloe: the robot's user reaches the board without root
KERNEL=="ttyAMA[0-9]*|serial[0-9]*", GROUP="dialout", MODE="0660"
SUBSYSTEM=="spidev", GROUP="spi", MODE="0660"
SUBSYSTEM=="i2c-dev", GROUP="i2c", MODE="0660"
SUBSYSTEM=="gpio", KERNEL=="gpiochip*", GROUP="gpio", MODE="0660"
"""


@dataclass(frozen=True)
class Action:
    what: str
    command: tuple[str, ...] = ()
    path: Path | None = None
    content: str = ""
    mode: int = 0o644
    ensure_lines: tuple[str, ...] = ()
    """With ``path``: append each of these lines unless the file already has it (the file is kept)."""

    def describe(self) -> str:
        if self.ensure_lines:
            body = "".join(f"    + {line}\n" for line in self.ensure_lines)
            return f"* {self.what}\n  ensure {self.path} has the lines:\n{body}"
        if self.path is not None:
            body = "".join(f"    | {line}\n" for line in self.content.splitlines())
            return f"* {self.what}\n  write {self.path} (mode {self.mode:o}):\n{body}"
        return f"* {self.what}\n  run: {shlex.join(self.command)}\n"

    def do(self) -> None:
        if self.ensure_lines:
            assert self.path is not None
            have = self.path.read_text().splitlines() if self.path.exists() else []
            missing = [line for line in self.ensure_lines if line not in have]
            with self.path.open("a") as f:
                f.writelines(line + "\n" for line in missing)
        elif self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.write_text(self.content)
            os.chmod(self.path, self.mode)
        else:
            subprocess.run(self.command, check=True)


def rt_cpu(config: RobotConfig) -> int:
    """The CPU hwbridge's cycle runs on (the last one unless the config says)."""
    return config.hwbridge.cpu if config.hwbridge.cpu >= 0 else (os.cpu_count() or 1) - 1


def units(config: RobotConfig, config_path: Path, python: str) -> dict[str, str]:
    """Unit file name -> content, from the templates in deploy/systemd/."""
    cpu = rt_cpu(config)
    values = {"robot": config.name, "user": USER, "python": python, "config": str(config_path),
              "cpu": str(cpu), "cpus": str(cpu)}
    out = {}
    for template in sorted(SYSTEMD_TEMPLATES.iterdir()):
        text = template.read_text()
        for key, value in values.items():
            text = text.replace("{" + key + "}", value)
        out[template.name] = text
    return out


def services_of(config: RobotConfig) -> list[str]:
    """The template-unit services this robot runs (hwbridge has its own unit; no simulator on a robot)."""
    return [s for s in config.services if s not in ("hwbridge", "sim")]


def install_plan(config: RobotConfig, config_path: Path, host: str = "") -> list[Action]:
    python = sys.executable  # the environment icefloe is installed in (the checkout's .venv, or a wheel's)
    cpu = rt_cpu(config)
    plan = [
        Action("system packages: the real-time test tool, GPIO and I2C tools",
               ("apt-get", "install", "-y", "rt-tests", "gpiod", "i2c-tools", "python3-venv")),
        Action(f"a system user {USER!r} for the services, in the hardware groups",
               ("sh", "-c", f"id -u {USER} >/dev/null 2>&1 || useradd --system --create-home {USER}")),
    ]
    plan += [Action(f"group {g}", ("sh", "-c", f"getent group {g} >/dev/null || groupadd --system {g}"))
             for g in GROUPS]
    plan += [
        Action(f"add {USER} to {', '.join(GROUPS)}", ("usermod", "-aG", ",".join(GROUPS), USER)),
        Action("device permissions for the serial port, SPI, I2C and GPIO",
               path=Path("/etc/udev/rules.d/99-icefloe.rules"), content=UDEV_RULES),
        Action("reload udev rules", ("udevadm", "control", "--reload-rules")),
        Action("boot config: serial port, SPI and I2C on (takes effect after a reboot)",
               path=BOOT_CONFIG, ensure_lines=BOOT_LINES),
        Action("free the serial port from the login console, and keep CPU "
               f"{cpu} for hwbridge's cycle alone (take effect after a reboot)",
               ("sed", "-i", "-e", "s/console=serial0,[0-9]* //",
                "-e", f"/isolcpus=/! s/$/ isolcpus={cpu}/", str(BOOT_CONFIG.parent / "cmdline.txt"))),
        Action(f"the runtime folder {config.runtime_dir} for the services' sockets, at every boot, "
               f"private to {USER}",
               path=Path("/etc/tmpfiles.d/icefloe.conf"),
               content=f"d {config.runtime_dir} 0700 {USER} {USER} -\n"),
        Action("create it now", ("systemd-tmpfiles", "--create", "/etc/tmpfiles.d/icefloe.conf")),
    ]
    if config.zenoh.access_control and config.zenoh.credentials:
        creds_cmd = [python, "-m", "icefloe.cli", "credentials", str(config_path)]
        if host:
            creds_cmd += ["--host", host]
        plan += [
            Action("this robot's credentials (made once, private, never printed)", tuple(creds_cmd)),
            Action(f"the credentials readable by {USER} only",
                   ("chown", f"{USER}:{USER}", config.zenoh.credentials)),
        ]
    for name, text in units(config, config_path, python).items():
        plan.append(Action(f"systemd unit {name}", path=UNIT_DIR / name, content=text))
    enable = ["icefloe.target", "icefloe-router.service", "icefloe-hwbridge.service",
              *(f"icefloe@{s}.service" for s in services_of(config))]
    plan += [
        Action("reload systemd", ("systemctl", "daemon-reload")),
        Action(f"enable and start: {' '.join(enable)}", ("systemctl", "enable", "--now", *enable)),
    ]
    return plan


def remove_plan(config: RobotConfig) -> list[Action]:
    names = ["icefloe.target", "icefloe-router.service", "icefloe-hwbridge.service",
             *(f"icefloe@{s}.service" for s in services_of(config))]
    plan = [Action(f"stop and disable: {' '.join(names)}", ("systemctl", "disable", "--now", *names))]
    plan += [Action(f"remove {UNIT_DIR / n}", ("rm", "-f", str(UNIT_DIR / n)))
             for n in sorted(p.name for p in SYSTEMD_TEMPLATES.iterdir())]
    plan += [
        Action("remove the udev rules", ("rm", "-f", "/etc/udev/rules.d/99-icefloe.rules")),
        Action("reload systemd", ("systemctl", "daemon-reload")),
    ]
    return plan


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("action", choices=["install", "remove"])
    p.add_argument("config", help="robot config file or name")
    p.add_argument("--dry-run", action="store_true", help="print every action, change nothing")
    p.add_argument("--host", default="", help="the robot's address, written into its credentials file")
    args = p.parse_args(argv)
    cfg = config_mod.load(args.config)
    path = Path(cfg.source).resolve()
    plan = install_plan(cfg, path, args.host) if args.action == "install" else remove_plan(cfg)
    verb = "would do" if args.dry_run else "doing"
    print(f"icefloe {args.action} for robot {cfg.name!r} ({path}): {verb} {len(plan)} steps")
    for action in plan:
        print(action.describe(), end="", flush=True)
        if not args.dry_run:
            action.do()
    if args.action == "install":
        print(f"\nDone{' (dry run: nothing changed)' if args.dry_run else ''}. The robot runs as systemd units "
              f"under icefloe.target: `journalctl -u 'icefloe*' -f` follows its logs. "
              f"Reboot once for the boot config to take effect.")
        if cfg.zenoh.access_control:
            print(f"Its credentials are in {cfg.zenoh.credentials}: give that file to whoever drives it.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
