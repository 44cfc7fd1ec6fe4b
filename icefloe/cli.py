"""The `icefloe` command.

    icefloe up [CONFIG] [--sim] [--no-viz]     run a robot's services (default: the simulated robot)
    icefloe router [CONFIG]                    run only the Zenoh router
    icefloe status                             which services are alive, per robot
    icefloe topics                             keys seen on the bus, with rates
    icefloe echo KEY                           decoded messages as JSON lines
    icefloe pub KEY JSON [--rate HZ]           publish a message (checked against the schema)
    icefloe query KEY [JSON]                   ask a queryable (odom/reset, info, cmd/motion ...)
    icefloe hz KEY                             message rate of a key
    icefloe schemas [--check]                  regenerate schemas/json (or check it is current)
    icefloe config [CONFIG]                    check a robot config and print it resolved
    icefloe viz [--connect EP] [--robot NAME]  live Rerun view of the robots on a bus (--save F.rrd, --serve)
    icefloe credentials [CONFIG] [--host IP]   make the robot's credentials file (once)
    icefloe router --lab DIR                   a lab router for the robots whose credentials are in DIR

KEY is a full key (``icefloe/sim/odom/pose``, wildcards allowed) or a name from
the key table (``odom/pose``), taken on the robot named by ``--robot`` or the
config. Every bus command takes ``--connect tcp/<robot-ip>:7447``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import sys
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec

from . import config as config_mod
from .config import RobotConfig
from .errors import BadPayload, ConfigError, IcefloeError
from .runtime import Node, RawSample, load_config, run_async
from .schemas import codec, keys


def _resolve_key(key: str, robot: str) -> str:
    return key if key.startswith(keys.PREFIX + "/") else keys.key(robot, key)


def _printable(value: Any) -> Any:
    """Plain JSON-able data, with byte strings shown as their length (images are large)."""
    if isinstance(value, bytes | bytearray):
        return f"<{len(value)} bytes>"
    if isinstance(value, dict):
        return {k: _printable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_printable(v) for v in value]
    return value


def describe(raw: RawSample) -> Any:
    """Decode a sample by the key table (or generically) into printable data."""
    topic = keys.topic_of(raw.key)
    if topic is not None and topic.kind != "query":
        msg = codec.decode(raw.payload, raw.encoding, topic.type, raw.key)
        return _printable(msgspec.to_builtins(msg, builtin_types=(bytes,)))
    return _printable(codec.to_builtins(raw.payload, raw.encoding))


class _Cli:
    def __init__(self, args: argparse.Namespace, config: RobotConfig) -> None:
        self.args = args
        self.config = config
        self.robot = args.robot or config.name

    def node(self) -> Node:
        return Node("cli", self.config, announce=False, retry=False)

    async def status(self) -> int:
        async with self.node() as node:
            tokens = await node.alive(self.args.robot or "*")
        by_robot: dict[str, list[str]] = defaultdict(list)
        for token in tokens:
            _, robot, _, service = token.split("/", 3)
            if service not in by_robot[robot]:
                by_robot[robot].append(service)
        if not by_robot:
            print("no robot is alive on this bus")
            return 1
        for robot, services in sorted(by_robot.items()):
            print(f"{robot}: {' '.join(sorted(services))}")
        return 0

    async def topics(self) -> int:
        counts: dict[str, int] = defaultdict(int)
        async with self.node() as node:
            sub = node.subscribe_raw(f"{keys.PREFIX}/{self.args.robot or '*'}/**", maxsize=100_000)
            await _drain(sub, self.args.duration, lambda raw: counts.__setitem__(raw.key, counts[raw.key] + 1))
        for key in sorted(counts):
            topic = keys.topic_of(key)
            kind = topic.type.__name__ if topic else "?"
            print(f"{key:<44} {counts[key] / self.args.duration:8.1f} Hz  {kind}")
        return 0

    async def echo(self) -> int:
        key = _resolve_key(self.args.key, self.robot)
        wildcard = "*" in key
        seen = 0
        async with self.node() as node:
            sub = node.subscribe_raw(key)

            def show(raw: RawSample) -> None:
                nonlocal seen
                try:
                    text = json.dumps(describe(raw))
                except (BadPayload, msgspec.DecodeError, IcefloeError) as exc:
                    text = json.dumps({"error": str(exc)})
                print(f"{raw.key} {text}" if wildcard else text, flush=True)
                seen += 1
                if self.args.count and seen >= self.args.count:
                    raise _Done

            with contextlib.suppress(_Done):
                await _drain(sub, self.args.duration, show)
        return 0

    async def hz(self) -> int:
        key = _resolve_key(self.args.key, self.robot)
        async with self.node() as node:
            sub = node.subscribe_raw(key, maxsize=100_000)
            end = time.monotonic() + (self.args.duration or float("inf"))
            while time.monotonic() < end:
                stamps: list[float] = []
                await _drain(sub, 1.0, lambda raw, into=stamps: into.append(raw.received))
                rate = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 2 else 0.0
                print(f"{key}: {rate:.1f} Hz ({len(stamps)} messages in the last second)", flush=True)
        return 0

    async def pub(self) -> int:
        key = _resolve_key(self.args.key, self.robot)
        topic = keys.topic_of(key)
        if topic is None or topic.kind == "query":
            known = ", ".join(t.name for t in keys.TABLE.values() if t.kind != "query")
            raise IcefloeError(f"{key}: not a topic one can publish to (known: {known})")
        message = codec.decode(self.args.json.encode(), codec.JSON, topic.type, key)
        async with self.node() as node:
            await asyncio.sleep(0.2)  # let the router learn our publisher before the first put
            pub = node.publisher(topic) if key == node.key(topic) else None
            payload = codec.encode(message)
            period = 1.0 / self.args.rate if self.args.rate else 0.0
            sent = 0
            while True:
                if pub is not None:
                    pub.put(message)
                else:
                    node.session.put(key, payload, encoding=codec.MSGPACK)
                sent += 1
                if not period or (self.args.count and sent >= self.args.count):
                    break
                await asyncio.sleep(period)
            await asyncio.sleep(0.1)
        return 0

    async def query(self) -> int:
        key = _resolve_key(self.args.key, self.robot)
        topic = keys.topic_of(key)
        if topic is None or topic.kind != "query":
            known = ", ".join(t.name for t in keys.TABLE.values() if t.kind == "query")
            raise IcefloeError(f"{key}: not a queryable (known: {known})")
        request = codec.decode((self.args.json or "{}").encode(), codec.JSON, topic.type, key)
        robot, _ = keys.split(key)
        async with self.node() as node:
            reply = await node.query(topic, request, timeout=self.args.timeout, robot=robot)
        print(json.dumps(_printable(msgspec.to_builtins(reply, builtin_types=(bytes,)))))
        return 0


class _Done(Exception):
    pass


async def _drain(sub: Any, duration: float | None, handle: Any) -> None:
    """Feed samples to ``handle`` for ``duration`` seconds (None = until Ctrl-C)."""
    async def loop() -> None:
        async for raw in sub:
            handle(raw)

    if duration:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(loop(), duration)
    else:
        await loop()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="icefloe", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    def bus(name: str, help_: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help_)
        sp.add_argument("--config", help="robot config (default: the simulated robot)")
        sp.add_argument("--connect", action="append", help="Zenoh endpoint, e.g. tcp/10.0.0.5:7447")
        sp.add_argument("--robot", help="robot name (default: the config's)")
        sp.add_argument("--credentials", help="a robot's credentials file (name, address, user, password)")
        return sp

    up = sub.add_parser("up", help="run every service of a robot")
    up.add_argument("config", nargs="?", help="robot config file or name (default: sim)")
    up.add_argument("--sim", action="store_true", help="use the simulated board whatever the config says")
    up.add_argument("--no-viz", action="store_true", help="do not open the Rerun viewer")
    up.add_argument("--only", help="comma-separated services to run")
    up.add_argument("--skip", help="comma-separated services not to run")
    router = sub.add_parser("router", help="run the Zenoh router only")
    router.add_argument("config", nargs="?")
    router.add_argument("--lab", help="folder of robots' credentials files: route and guard all of them")
    creds = sub.add_parser("credentials", help="make this robot's credentials file if it has none")
    creds.add_argument("config", nargs="?")
    creds.add_argument("--host", help="the robot's address, written into the file for laptops")
    creds.add_argument("--replace", action="store_true", help="make a new password even if one exists")
    creds.add_argument("--sheet", action="store_true",
                       help="print a sheet with the password, to hand to whoever has the robot")
    bus("status", "which services are alive")
    bus("topics", "keys seen, with rates").add_argument("--duration", type=float, default=3.0)
    echo = bus("echo", "print decoded messages as JSON lines")
    echo.add_argument("key")
    echo.add_argument("--count", type=int, default=0, help="stop after N messages")
    echo.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    hz = bus("hz", "message rate of a key")
    hz.add_argument("key")
    hz.add_argument("--duration", type=float, default=None)
    pub = bus("pub", "publish a message given as JSON")
    pub.add_argument("key")
    pub.add_argument("json")
    pub.add_argument("--rate", type=float, default=0.0, help="repeat at this rate, Hz")
    pub.add_argument("--count", type=int, default=0, help="with --rate: stop after N")
    query = bus("query", "ask a queryable")
    query.add_argument("key")
    query.add_argument("json", nargs="?")
    query.add_argument("--timeout", type=float, default=5.0)
    schemas = sub.add_parser("schemas", help="regenerate schemas/json")
    schemas.add_argument("--check", action="store_true", help="only check; exit 1 if stale")
    cfg = sub.add_parser("config", help="check a robot config and print it resolved")
    cfg.add_argument("config", nargs="?")
    return p


def _up(args: argparse.Namespace) -> int:
    from . import launcher

    path = Path(args.config) if args.config else config_mod.DEFAULT_CONFIG
    if args.config and not path.suffix and not path.exists():
        path = config_mod.ROBOTS_DIR / f"{args.config}.toml"
    cfg = config_mod.load(path)
    if args.sim and cfg.board.backend != "sim":
        path = _sim_override(path, cfg)
        cfg = config_mod.load(path)
    services = args.only.split(",") if args.only else list(cfg.services)
    if not args.only and not args.no_viz and _can_show_viewer():
        services.append("viz")  # the laptop's view of the robot
    skip = args.skip.split(",") if args.skip else []
    launcher.up(cfg, path, [s for s in services if s not in skip])
    return 0


def _bus_config(args: argparse.Namespace) -> RobotConfig:
    """The config of a bus command, with --connect and --credentials applied."""
    cfg = load_config(args)
    if args.credentials:
        from .credentials import read

        creds = read(args.credentials)
        zenoh = msgspec.structs.replace(cfg.zenoh, user=creds.user, password=creds.password,
                                        connect=args.connect or creds.connect or cfg.zenoh.connect)
        cfg = msgspec.structs.replace(cfg, name=creds.robot, zenoh=zenoh)
        args.robot = args.robot or creds.robot
    return cfg


def _router(args: argparse.Namespace) -> int:
    from . import router
    from .runtime import run

    if not args.lab:
        run(router.main, ["--config", args.config] if args.config else [])
        return 0
    owners = router.lab_owners(Path(args.lab))

    async def lab(config: RobotConfig) -> None:
        names = ", ".join(robot for robot, _, _ in owners)
        await router.serve(config, router.router_config(config, owners), f"lab router for {names}")

    run(lab, ["--config", args.config] if args.config else [])
    return 0


def _credentials(args: argparse.Namespace) -> int:
    from .credentials import make

    cfg = config_mod.load(args.config)
    if not cfg.zenoh.credentials:
        raise ConfigError(f"{cfg.source}: zenoh.credentials is not set: say where the file goes")
    port = cfg.zenoh.listen[0].rsplit(":", 1)[-1] if cfg.zenoh.listen else "7447"
    connect = [f"tcp/{args.host}:{port}"] if args.host else []
    path, created = make(cfg.zenoh.credentials, cfg.name, connect, replace=args.replace)
    # The password is printed only on request (--sheet), never logged.
    print(f"{'made' if created else 'kept'} {path} for robot {cfg.name!r} (mode 0600)")
    if args.sheet:
        from .credentials import read

        c = read(path)
        print(f"\n  icefloe robot {c.robot!r}\n  user:     {c.user}\n  password: {c.password}\n"
              f"  connect:  {', '.join(c.connect) or '(the robot address), port 7447'}\n\n"
              f"  Save these four lines as {c.robot}.credentials and run\n"
              f"  icefloe status --credentials {c.robot}.credentials\n")
    return 0


def _sim_override(path: Path, cfg: RobotConfig) -> Path:
    """A config that extends ``path`` with the simulated board (for `up --sim`)."""
    out = cfg.runtime_dir / "sim-override.toml"
    out.parent.mkdir(parents=True, exist_ok=True)
    services = cfg.services if "sim" in cfg.services else ["sim", *cfg.services]
    out.write_text(f'extends = "{path.resolve()}"\nservices = {json.dumps(services)}\n\n'
                   '[board]\nbackend = "sim"\nserial_port = "{run_dir}/ttyPPI"\n')
    return out


def _can_show_viewer() -> bool:
    try:
        import rerun  # noqa: F401
    except ImportError:
        return False
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["viz"]:  # the viewer has its own options (and needs the `viz` extra)
        try:
            from .services.viz.__main__ import cli as viz
        except ImportError as exc:
            print(f"icefloe: viz needs rerun-sdk: pip install -e '.[viz]' ({exc})", file=sys.stderr)
            return 2
        viz(argv[1:])
        return 0
    args = _parser().parse_args(argv)
    try:
        if args.command == "up":
            return _up(args)
        if args.command == "schemas":
            from .schemas import export

            if args.check:
                bad = export.stale()
                for name in bad:
                    print(f"stale: schemas/json/{name} (run `icefloe schemas`)")
                return 1 if bad else 0
            print(f"wrote {len(export.write())} schemas to {export.JSON_DIR}")
            return 0
        if args.command == "config":
            cfg = config_mod.load(args.config)
            print(json.dumps(msgspec.to_builtins(cfg), indent=2))
            return 0
        if args.command == "router":
            return _router(args)
        if args.command == "credentials":
            return _credentials(args)
        cli = _Cli(args, _bus_config(args))
        return run_async(getattr(cli, args.command)())
    except (ConfigError, IcefloeError) as exc:
        print(f"icefloe: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
