"""The robot's Zenoh router: the one process that listens on the robot's port.

Every service on the robot is a Zenoh client of this router, so no multicast is
needed; laptops connect to the same port. `icefloe up` starts it first.

With ``[zenoh] access_control = true`` the router requires a Zenoh user and
password from everyone who connects: the robot's own user (from its credentials
file) and the public read-only user `guest`. What each may do is in
``deploy/zenoh/acl/``: deny by default, everyone may watch every robot, only the
robot's own user may command it (`access_control` builds Zenoh's rules from those
files and the key table). With ``[zenoh] lab`` the router also joins a lab router
and trusts that link (``lab-link.json5``). A lab router (``icefloe router --lab
DIR``) guards every robot whose credentials are in DIR (docs/lab.md).

Zenoh reads users and passwords from a file only: the router writes it into its
private runtime folder (0700), without following links, mode 0600, and removes it
as soon as Zenoh has read it, while the router starts.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import zenoh

from . import paths, ros2
from .config import RobotConfig, check_lab, private_dir, protocol
from .credentials import GUEST_PASSWORD, GUEST_USER, TA_ROBOT
from .errors import ConfigError
from .runtime import run, zenoh_config
from .schemas import keys

ACL_DIR = paths.packaged("zenoh", "acl")


@dataclass(frozen=True)
class Owner:
    """A robot and the Zenoh user that may command it."""

    robot: str
    user: str
    password: str


def _acl_part(name: str, **fill: str | list[str]) -> dict:
    """``deploy/zenoh/acl/<name>.json5`` with its ``{placeholders}`` filled in, as plain data.

    A list replaces a quoted placeholder with that many strings: ``["{protocols}"]`` -> ``["ws"]``.
    """
    text = (ACL_DIR / f"{name}.json5").read_text()
    for placeholder, value in fill.items():
        if isinstance(value, list):
            text = text.replace(f'"{{{placeholder}}}"', ", ".join(json.dumps(v) for v in value))
        else:
            text = text.replace(f"{{{placeholder}}}", value)
    return json.loads(zenoh.Config.from_json5(text).get_json("access_control"))  # Zenoh reads its JSON5


def _ros2_owner_part(robot: str, user: str, domain: int, namespace: str) -> dict:
    """`ros2-owner.json5` for a robot whose ROS 2 topics are in ``namespace`` (``/penguin1``)."""
    return _acl_part("ros2-owner", robot=robot, user=user, ros2_domain=str(domain),
                     ros2_namespace=namespace.strip("/"), ros2_token_namespace=ros2.mangle(namespace.rstrip("/")))


def access_control(owners: Sequence[tuple[str, str]], lab_protocols: Sequence[str] = (),
                   localizers: Sequence[str] = (), ros2_domain: int = 0,
                   ros2_namespaces: Mapping[str, str] | None = None) -> dict:
    """Zenoh's ``access_control`` for (robot, user) pairs: `everyone.json5` once, `owner.json5` per
    robot, `ta.json5` for the users whose robot is `TA_ROBOT`, `localizer.json5` per user of
    ``localizers`` (the lab's external localizer), and `lab-link.json5` when the router joins a
    lab over ``lab_protocols``.

    ROS 2 (docs/ros2.md): everyone may watch the ROS 2 domain ``ros2_domain``; each robot's owner gets
    `ros2-owner.json5` for the robot's namespace, ``ros2_namespaces[robot]`` if given, else
    ``/<robot>`` (none for a robot whose name is not a ROS 2 name: its owner has no ROS 2 keys)."""
    read_only = [keys.key("*", topic) for topic in keys.READ_ONLY_QUERIES]
    domain = str(ros2_domain)
    parts = [_acl_part("everyone", read_only_queries=read_only, ros2_domain=domain)]
    parts += [_acl_part("owner", robot=robot, user=user) for robot, user in owners if robot != TA_ROBOT]
    for robot, user in owners:
        namespace = ros2.robot_namespace(robot, (ros2_namespaces or {}).get(robot, ""))
        if robot != TA_ROBOT and namespace is not None:
            parts.append(_ros2_owner_part(robot, user, ros2_domain, namespace))
    tas = sorted({user for robot, user in owners if robot == TA_ROBOT})
    if tas:
        parts.append(_acl_part("ta", users=tas))
    parts += [_acl_part("localizer", user=user) for user in localizers]
    if lab_protocols:
        parts.append(_acl_part("lab-link", protocols=sorted(set(lab_protocols)), ros2_domain=domain))
    return {"enabled": True, "default_permission": "deny",
            **{field: [item for part in parts for item in part[field]]
               for field in ("rules", "subjects", "policies")}}


def permits(acl: dict, user: str, message: str, key_expr: str, flow: str = "ingress") -> bool:
    """Whether Zenoh's ``acl`` (as `access_control` builds it) lets a session logged in as ``user``
    send ``message`` (``put``, ``query``, ``declare_subscriber``, ...) on ``key_expr``: the router's
    own decision, taken beforehand, so the web API's HTTP bridge can say no with a reason.

    As Zenoh decides: a rule applies if it names the message and the flow and one of its key
    expressions INCLUDES ``key_expr``; a deny rule wins, else an allow rule, else the default.
    A subject is a user's if it names the user or names nothing (everyone); a subject of link
    protocols or interfaces is a link's, never an HTTP client's.
    """
    def mine(subject: dict) -> bool:
        conditions = {k for k, v in subject.items() if k != "id" and v is not None}
        return not conditions or (conditions == {"usernames"} and user in subject["usernames"])

    subjects = {s["id"] for s in acl["subjects"] if mine(s)}
    rules = {r for p in acl["policies"] if subjects & set(p["subjects"]) for r in p["rules"]}
    expr = zenoh.KeyExpr.autocanonize(key_expr)
    verdicts = {r["permission"] for r in acl["rules"]
                if r["id"] in rules and message in r["messages"] and flow in r["flows"]
                and any(zenoh.KeyExpr(k).includes(expr) for k in r["key_exprs"])}
    return "deny" not in verdicts and ("allow" in verdicts or acl.get("default_permission") == "allow")


def owners_of(config: RobotConfig) -> list[Owner]:
    """The robot's own user, when its config asks for access control (else nobody: no login)."""
    if not config.zenoh.access_control:
        return []
    if not config.zenoh.user:
        where = config.zenoh.credentials or "(zenoh.credentials is not set)"
        raise ConfigError(f"{config.source}: zenoh.access_control is on but there are no credentials "
                          f"at {where}: run `icefloe credentials {config.source}`")
    if config.zenoh.user == GUEST_USER:
        raise ConfigError(f"{config.source}: the robot's user may not be {GUEST_USER!r}: that is everybody's "
                          "read-only login (rename the robot, then `icefloe credentials --replace`)")
    return [Owner(config.name, config.zenoh.user, config.zenoh.password)]


def check_router(config: RobotConfig) -> None:
    """`ConfigError` if the router would refuse this config (`icefloe up` asks before it starts
    anything): credentials for access control, the robot's user, the lab link, Zenoh's own config file."""
    owners_of(config)
    try:
        router_config(config, [])
    except zenoh.ZError as exc:
        raise ConfigError(f"{config.source}: zenoh.config: Zenoh refused it: {exc}") from None


def router_config(config: RobotConfig, owners: Sequence[Owner], users_file: Path | None = None,
                  localizers: Sequence[str] = ()) -> zenoh.Config:
    """Zenoh config of the router: with access control for ``owners`` (and the guest) when
    there are any, their passwords in ``users_file`` (`write_users`); joined to the lab router
    of ``[zenoh] lab`` if there is one, logged in there with the robot's own credentials."""
    zc = zenoh_config(config, mode="router", listen=config.zenoh.listen, connect=config.zenoh.lab)
    # Read-only admin space: who declared what (`icefloe topics -v`, `info`, `services`; icefloe/graph.py).
    zc.insert_json5("adminspace", '{"enabled": true, "permissions": {"read": true, "write": false}}')
    listen = json.loads(zc.get_json("listen/endpoints"))  # the extra config file may add some
    check_lab(config.zenoh, listen if isinstance(listen, list) else [], config.source)
    # No shared-memory transport: with it, every payload over 3 KiB that passes the router goes
    # through 16 MiB segments mapped into the sender, the router and each receiver (+20 to +40 MB
    # of RSS in each, docs/hostile-input.md), and a local process could make everyone map its own.
    # Our large messages (camera JPEGs, 2 Hz) cost a copy instead.
    zc.insert_json5("transport/shared_memory/enabled", "false")
    if owners:
        if users_file is None:
            raise ValueError("access control needs the users file (write_users)")
        zc.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users_file)))
        lab = [protocol(e) for e in config.zenoh.lab]
        # ROS 2's keys of this config's domain; the robot's own namespace from its config (a lab
        # router's robots: `/<robot>`, docs/ros2.md).
        acl = access_control([(o.robot, o.user) for o in owners], lab, localizers, config.ros2.domain_id,
                             {config.name: config.ros2.namespace})
        zc.insert_json5("access_control", json.dumps(acl))
    return zc


def write_users(folder: Path, owners: Sequence[Owner]) -> Path:
    """The users and passwords Zenoh checks logins against (``user:password`` lines, the guest
    last), in ``folder`` made private first; created fresh (never through a planted link), 0600."""
    path = private_dir(folder) / "zenoh-users"
    with contextlib.suppress(FileNotFoundError):
        path.unlink()  # one left by a router that was killed; a symlink goes, not its target
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.writelines(f"{o.user}:{o.password}\n" for o in owners)
        f.write(f"{GUEST_USER}:{GUEST_PASSWORD}\n")
    return path


def open_router(config: RobotConfig, owners: Sequence[Owner], localizers: Sequence[str] = ()) -> zenoh.Session:
    """Open the router's session; the users file exists only while Zenoh reads it."""
    users = write_users(config.runtime_dir, owners) if owners else None
    try:
        return zenoh.open(router_config(config, owners, users, localizers))
    finally:
        if users is not None:
            users.unlink(missing_ok=True)


async def serve(config: RobotConfig, owners: Sequence[Owner], what: str, localizers: Sequence[str] = ()) -> None:
    session = open_router(config, owners, localizers)
    token = session.liveliness().declare_token(keys.alive_key(config.name, "router"))
    joined = f", joined to the lab router at {', '.join(config.zenoh.lab)}" if config.zenoh.lab else ""
    print(f"{what} listening on {', '.join(config.zenoh.listen)}{joined}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        token.undeclare()
        session.close()


async def main(config: RobotConfig) -> None:
    owners = owners_of(config)
    acl = " with access control" if owners else ""
    await serve(config, owners, f"router for {config.name!r}{acl}")


def lab_owners(lab_dir: Path) -> list[Owner]:
    """The robot and user of every credentials file in a folder (a TA's: robot `TA_ROBOT`)."""
    from .credentials import read

    owners = [Owner(c.robot, c.user, c.password) for c in map(read, sorted(lab_dir.glob("*.credentials")))]
    if not owners:
        raise ConfigError(f"{lab_dir}: no *.credentials files: nothing to route for")
    if len({o.user for o in owners}) < len(owners) or GUEST_USER in {o.user for o in owners}:
        raise ConfigError(f"{lab_dir}: two credentials files have the same user (or one is {GUEST_USER!r})")
    return owners


async def lab_main(config: RobotConfig, lab_dir: Path) -> None:
    """A lab router: access control for every robot whose credentials are in ``lab_dir``."""
    if config.zenoh.lab:
        raise ConfigError(f"{config.source}: a lab router does not join another (zenoh.lab is set)")
    owners = lab_owners(lab_dir)
    robots = [o.robot for o in owners if o.robot != TA_ROBOT]
    if not robots:
        raise ConfigError(f"{lab_dir}: only a TA's credentials: no robot to route for")
    tas = [o.user for o in owners if o.robot == TA_ROBOT]
    ta = f", TA account {', '.join(tas)}" if tas else ""
    # The lab's own credentials file (its robot: this config's name) is the lab's external
    # localizer's login: it alone may publish the robots' `extloc/pose` (docs/extloc.md).
    localizers = [o.user for o in owners if o.robot == config.name]
    await serve(config, owners, f"lab router for {', '.join(robots)}{ta}", localizers)


if __name__ == "__main__":
    run(main, description="icefloe's Zenoh router")
