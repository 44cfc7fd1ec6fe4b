"""Verbs that run and set up a robot: up, router, credentials, config."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .. import config as config_mod
from ..config import RobotConfig
from ..errors import ConfigError
from ..services.viz.viewer import display_problem, how_to_look
from .common import add_config_argument


def up(args: argparse.Namespace) -> int:
    from .. import launcher

    path = config_mod.find(args.config)
    cfg = config_mod.load(path)
    if args.sim and cfg.board.backend != "sim":
        path = sim_override(path, cfg)
        cfg = config_mod.load(path)
    services = args.only.split(",") if args.only else [*cfg.services, *(p for p in cfg.programs
                                                                        if p not in cfg.services)]
    if not args.only and not args.no_viz:
        if (problem := viewer_problem()) is None:
            services.append("viz")  # the laptop's view of the robot
        else:
            print(f"[up] {problem}, so no viewer; {how_to_look()}", flush=True)
    skip = args.skip.split(",") if args.skip else []
    return launcher.up(cfg, path, [s for s in services if s not in skip],  # checks the robot first
                       fork_server=not args.no_fork_server)


def sim_override(path: Path, cfg: RobotConfig) -> Path:
    """A config that extends ``path`` with the simulated board (for `up --sim`)."""
    out = config_mod.private_dir(cfg.runtime_dir) / "sim-override.toml"
    services = cfg.services if "sim" in cfg.services else ["sim", *cfg.services]
    out.write_text(f'extends = "{path.resolve()}"\nservices = {json.dumps(services)}\n\n'
                   '[board]\nbackend = "sim"\nserial_port = "{run_dir}/ttyPPI"\n')
    return out


def viewer_problem() -> str | None:
    """Why `up` cannot open the Rerun viewer here (one line), or None if it can."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        return "the Rerun SDK is not installed (pip install 'icefloe[viz]')"
    return display_problem()


def router(args: argparse.Namespace) -> int:
    from .. import router as router_mod
    from ..runtime import run

    argv = ["--config", args.config] if args.config else []
    if not args.lab:
        run(router_mod.main, argv)
        return 0
    lab_dir = Path(args.lab)
    router_mod.lab_owners(lab_dir)  # a bad folder: say so before anything starts

    async def lab(config: RobotConfig) -> None:
        await router_mod.lab_main(config, lab_dir)

    run(lab, argv)
    return 0


def credentials(args: argparse.Namespace) -> int:
    from ..credentials import make, read

    cfg = config_mod.load(args.config)
    if not cfg.zenoh.credentials:
        raise ConfigError(f"{cfg.source}: zenoh.credentials is not set: say where the file goes")
    port = cfg.zenoh.listen[0].rsplit(":", 1)[-1] if cfg.zenoh.listen else "7447"
    connect = [f"tcp/{args.host}:{port}"] if args.host else []
    path, created = make(cfg.zenoh.credentials, cfg.name, connect, replace=args.replace)
    # The password is printed only on request (--sheet), never logged.
    print(f"{'made' if created else 'kept'} {path} for robot {cfg.name!r} (mode 0600)")
    if args.sheet:
        c = read(path)
        print(f"\n  icefloe robot {c.robot!r}\n  user:     {c.user}\n  password: {c.password}\n"
              f"  connect:  {', '.join(c.connect) or '(the robot address), port 7447'}\n\n"
              f"  Save these four lines as {c.robot}.credentials and run\n"
              f"  icefloe status --credentials {c.robot}.credentials\n")
    return 0


def show_config(args: argparse.Namespace) -> int:
    cfg = config_mod.load(args.config)
    print(json.dumps(config_mod.printable(cfg), indent=2))  # the password as "***"
    return 0


def register(verbs: argparse._SubParsersAction) -> None:
    p = verbs.add_parser("up", help="run a robot: its router and every service (default: the simulated robot)",
                         description="Run a robot's router and services as processes, each restarted if it "
                                     "dies; Ctrl-C stops them all.")
    add_config_argument(p, positional=True)
    p.add_argument("--sim", action="store_true", help="use the simulated board whatever the config says")
    p.add_argument("--no-viz", action="store_true", help="do not open the Rerun viewer")
    p.add_argument("--no-fork-server", action="store_true",
                   help="start each service as a fresh Python (more memory; icefloe.forkserver says why not)")
    p.add_argument("--only", metavar="A,B", help="comma-separated services to run (instead of the config's list)")
    p.add_argument("--skip", metavar="A,B", help="comma-separated services not to run")
    p.set_defaults(run=up)

    p = verbs.add_parser("router", help="run only a robot's Zenoh router, or a lab router (--lab)",
                         description="Run only a robot's Zenoh router (what `up` starts first), or with --lab "
                                     "the router of a lab of robots with access control (docs/lab.md).")
    add_config_argument(p, positional=True)
    p.add_argument("--lab", metavar="DIR", help="folder of robots' credentials files: route and guard all of them")
    p.set_defaults(run=router)

    p = verbs.add_parser("credentials", help="make a robot's credentials file (once), or print its sheet",
                         description="Make the credentials file of a robot with access control (a random "
                                     "password, mode 0600) where its config says, unless it exists; --sheet "
                                     "prints what a student needs to drive it (docs/lab.md).")
    add_config_argument(p, positional=True)
    p.add_argument("--host", help="the robot's address, written into the file for laptops")
    p.add_argument("--replace", action="store_true", help="make a new password even if one exists")
    p.add_argument("--sheet", action="store_true",
                   help="print a sheet with the password, to hand to whoever has the robot")
    p.set_defaults(run=credentials)

    p = verbs.add_parser("config", help="check a robot config and print it resolved",
                         description="Read a robot config (by name or path, with what it extends), check every "
                                     "key, and print the result as JSON; a bad config gets one line naming the "
                                     "file and the key.")
    add_config_argument(p, positional=True)
    p.set_defaults(run=show_config)
