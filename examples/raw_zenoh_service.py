"""A service written with raw Zenoh and the JSON Schemas only: no icefloe import.

This is what a student does in C, Rust or JavaScript; here in plain Python so you
can compare. It drives the robot forward a given distance, measured with the
wheel encoders, whenever someone asks:

    python examples/raw_zenoh_service.py --robot sim --connect tcp/127.0.0.1:7447
    # then, from anywhere (any Zenoh tool will do):
    z_put -k icefloe/sim/student/forward -v '{"distance": 0.3}'

Under `icefloe up` (a ``[programs.forward]`` table in the robot config) it needs no options:
the robot's name, router and credentials file come in ``ICEFLOE_ROBOT``, ``ICEFLOE_CONNECT``
and ``ICEFLOE_CREDENTIALS`` (docs/own-services.md). It holds the liveliness token
``icefloe/<robot>/alive/forward``, so `icefloe status` lists it with the robot's own services.

What it uses from the robot (schemas in schemas/json/, keys in each schema's
"x-icefloe-keys"):

* query  ``icefloe/<robot>/info``       -> RobotInfo (wheel size, counts per turn)
* sub    ``icefloe/<robot>/hw/wheels``  <- Wheels, MessagePack
* pub    ``icefloe/<robot>/cmd/twist``  -> Twist, sent as JSON (every command key takes JSON too)
* pub    ``icefloe/<robot>/cmd/stop``   -> Stop, a JSON object with no fields but the three below

Every command also says who sent it (``sender``), its number (``seq``) and when it
was issued (``stamp``): optional, but with them the robot puts our stop after the
twists we sent before it, even when the stop overtakes them on the way.
* sub    ``icefloe/<robot>/student/forward`` <- our own key: JSON {"distance": metres}

Zenoh calls us back on its own threads, so callbacks only hand data to the main
thread (a queue, or a lock-protected variable); the main thread does the work.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import os
import queue
import signal
import threading
import time
import tomllib
from pathlib import Path
from typing import Any

import msgspec
import zenoh

SCHEMAS = Path(__file__).resolve().parent.parent / "schemas" / "json"
SPEED = 0.15
"""Forward speed, m/s."""
CREEP, CREEP_DISTANCE = 0.04, 0.05
"""The last 5 cm at 4 cm/s: the wheels take a moment to stop, so arrive slowly."""
PERIOD = 0.1
"""Re-send the twist this often, s: the robot stops by itself 0.5 s after the last command."""
MAX_DISTANCE = 5.0
"""Longest drive we accept, m."""
WHEELS_WAIT = 5.0
"""How long a request waits for the first encoder reading, s."""

log = logging.getLogger("forward")


# ---------------------------------------------------------------- checking messages against the schemas

def schema(name: str) -> dict[str, Any]:
    """The JSON Schema of one message, e.g. schema("Wheels")."""
    return json.loads((SCHEMAS / f"{name}.json").read_text())


def problems(value: Any, node: dict[str, Any], root: dict[str, Any], where: str = "$") -> list[str]:
    """What is wrong with ``value`` under a schema node (the small part of JSON Schema ours use)."""
    if "$ref" in node:  # "#/$defs/Wheels"
        node = root["$defs"][node["$ref"].rsplit("/", 1)[1]]
    kind = node.get("type")
    types = {"object": dict, "array": list, "string": str, "boolean": bool}
    if kind in ("integer", "number"):
        ok = isinstance(value, int) if kind == "integer" else isinstance(value, int | float)
        if not ok or isinstance(value, bool):
            return [f"{where}: expected {kind}, got {value!r}"]
    elif kind in types and not isinstance(value, types[kind]):
        return [f"{where}: expected {kind}, got {type(value).__name__}"]
    if "enum" in node and value not in node["enum"]:
        return [f"{where}: {value!r} is not one of {node['enum']}"]
    found = []
    if kind == "object":
        found += [f"{where}: missing {k}" for k in node.get("required", []) if k not in value]
        for k, v in value.items():
            if k in node.get("properties", {}):
                found += problems(v, node["properties"][k], root, f"{where}.{k}")
            elif node.get("additionalProperties") is False:
                found.append(f"{where}: unknown field {k}")
    return found


class Checked:
    """Decodes and checks one message type: ``Checked("Wheels").decode(payload)``."""

    def __init__(self, name: str) -> None:
        self.name, self.schema = name, schema(name)

    def check(self, message: dict[str, Any]) -> dict[str, Any]:
        found = problems(message, self.schema, self.schema)
        if found:
            raise ValueError(f"{self.name}: {'; '.join(found)}")
        return message

    def decode(self, sample: zenoh.Sample) -> dict[str, Any]:
        payload = sample.payload.to_bytes()
        if str(sample.encoding).startswith("application/json"):
            return self.check(json.loads(payload))
        return self.check(msgspec.msgpack.decode(payload))

    def json(self, **fields: Any) -> bytes:
        return json.dumps(self.check(fields)).encode()


# ---------------------------------------------------------------- the service

def connect(args: argparse.Namespace) -> tuple[zenoh.Session, str]:
    """Open a Zenoh session as a client of the robot's router; returns it and the robot name."""
    name, endpoints, user, password = args.robot, args.connect.split(",") if args.connect else [], "", ""
    if args.config:  # a robot config file: take what we need from it
        toml = tomllib.loads(Path(args.config).read_text())
        z = toml.get("zenoh", {})
        name = name or toml.get("name")
        endpoints = endpoints or z.get("connect", [])
        user, password = z.get("user", ""), z.get("password", "")
    if args.credentials:  # the robot's credentials file: robot, user, password, connect
        creds = tomllib.loads(Path(args.credentials).expanduser().read_text())
        name = name or creds["robot"]
        endpoints = endpoints or creds.get("connect", [])
        user, password = creds["user"], creds["password"]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")  # the robot's router, nothing else
    conf.insert_json5("connect/endpoints", json.dumps(endpoints or ["tcp/127.0.0.1:7447"]))
    if user:  # robots with access control: user and password from the robot's credentials
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zenoh.open(conf), name or "sim"


def metres_per_tick(session: zenoh.Session, prefix: str) -> float:
    """Ask the robot's ``info`` queryable for its wheel size and encoder resolution."""
    info = Checked("RobotInfo")
    for _ in range(30):  # the robot may still be starting: ask for up to 30 s
        for reply in session.get(f"{prefix}/info", timeout=1.0):
            if reply.ok is not None:
                robot = info.decode(reply.ok)
                return math.pi * robot["wheel_diameter"] / robot["ticks_per_rev"]
        time.sleep(0.5)  # nobody answered (get returns at once when nobody serves the key)
    raise SystemExit(f"{prefix}/info: no answer (is the robot's info service running?)")


def main() -> None:
    parser = argparse.ArgumentParser(description="Drive forward on request (raw Zenoh example).")
    env = os.environ.get  # what `icefloe up` tells the programs it runs
    parser.add_argument("--robot", default=env("ICEFLOE_ROBOT"),
                        help="robot name (default: $ICEFLOE_ROBOT, from --config, else sim)")
    parser.add_argument("--connect", default=env("ICEFLOE_CONNECT"),
                        help="Zenoh endpoint of the robot, e.g. tcp/10.0.0.5:7447 (default: $ICEFLOE_CONNECT)")
    parser.add_argument("--config", help="robot config TOML (name, [zenoh] connect/user/password)")
    parser.add_argument("--credentials", default=env("ICEFLOE_CREDENTIALS") or None,
                        help="the robot's credentials file, to command a robot with access control "
                             "(default: $ICEFLOE_CREDENTIALS)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")

    stopping = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stopping.set())

    session, robot = connect(args)
    prefix = f"icefloe/{robot}"
    wheels_type, twist, stop = Checked("Wheels"), Checked("Twist"), Checked("Stop")
    k = metres_per_tick(session, prefix)

    latest: dict[str, Any] = {}
    lock = threading.Lock()
    have_wheels = threading.Event()
    requests: queue.Queue[float] = queue.Queue()

    def on_wheels(sample: zenoh.Sample) -> None:  # Zenoh thread: store and return
        try:
            wheels = wheels_type.decode(sample)
        except ValueError as exc:
            log.warning("%s: dropped: %s", sample.key_expr, exc)
            return
        with lock:
            latest["wheels"] = wheels
        have_wheels.set()

    def on_request(sample: zenoh.Sample) -> None:  # Zenoh thread
        try:
            distance = json.loads(sample.payload.to_bytes())["distance"]
            if isinstance(distance, bool) or not isinstance(distance, int | float) \
                    or not abs(distance) <= MAX_DISTANCE:
                raise ValueError(f"distance must be a number of metres within ±{MAX_DISTANCE}")
        except (ValueError, KeyError, TypeError) as exc:
            log.warning("%s: refused %r: %s", sample.key_expr, sample.payload.to_bytes(), exc)
            return
        requests.put(float(distance))

    subs = [session.declare_subscriber(f"{prefix}/hw/wheels", on_wheels),
            session.declare_subscriber(f"{prefix}/student/forward", on_request)]
    # "I am running": `icefloe status` lists the services that hold such a token.
    alive = session.liveliness().declare_token(f"{prefix}/alive/{os.environ.get('ICEFLOE_SERVICE', 'forward')}")
    json_encoding = zenoh.Encoding("application/json")
    # Who we are, our commands' numbers, and a clock that never jumps back (the wall clock
    # once, then the monotonic clock): the robot learns how far it is off its own.
    sender, numbers = str(session.zid()), itertools.count(1)
    wall0, mono0 = time.time_ns(), time.monotonic_ns()

    def issued() -> dict[str, Any]:
        return {"sender": sender, "seq": next(numbers), "stamp": wall0 + time.monotonic_ns() - mono0}

    def travelled(start: dict[str, Any]) -> float:
        with lock:
            now = latest["wheels"]
        ticks = (now["ticks_left"] - start["ticks_left"] + now["ticks_right"] - start["ticks_right"])
        return k * ticks / 2

    log.info("waiting for requests on %s/student/forward", prefix)
    while not stopping.is_set():
        try:
            distance = requests.get(timeout=0.2)
        except queue.Empty:
            continue
        # A request may come before the first encoder reading (we, or hwbridge, just started):
        # wait a moment for one rather than drop the request.
        if not have_wheels.wait(WHEELS_WAIT):
            log.warning("no %s/hw/wheels within %g s: is hwbridge running?", prefix, WHEELS_WAIT)
            continue
        with lock:
            start = latest["wheels"]
        log.info("driving %.3f m", distance)
        while (left := abs(distance) - abs(travelled(start))) > 0 and not stopping.is_set():
            speed = SPEED if left > CREEP_DISTANCE else CREEP
            command = twist.json(v=math.copysign(speed, distance), w=0.0, **issued())
            session.put(f"{prefix}/cmd/twist", command, encoding=json_encoding)
            time.sleep(PERIOD if left > CREEP_DISTANCE else PERIOD / 5)
        session.put(f"{prefix}/cmd/stop", stop.json(**issued()), encoding=json_encoding)
        log.info("done: %.3f m by the encoders", travelled(start))

    session.put(f"{prefix}/cmd/stop", stop.json(**issued()), encoding=json_encoding)  # never leave it moving
    for sub in subs:
        sub.undeclare()
    alive.undeclare()
    session.close()


if __name__ == "__main__":
    main()
