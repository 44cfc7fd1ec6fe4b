"""The robot's Zenoh router: the one process that listens on the robot's port.

Every service on the robot is a Zenoh client of this router, so no multicast is
needed; laptops connect to the same port. `icefloe up` starts it first.

With ``[zenoh] access_control = true`` the router requires a Zenoh user and
password from everyone who connects: the robot's own user (from its credentials
file) and the public read-only user `guest`; the access-control rules in
``deploy/zenoh/robot-acl.json5`` let only the robot's own user publish under
``icefloe/<robot>/`` and call its queryables. A lab router (``--lab``) does the
same for every robot of a lab (docs/lab.md).
"""

from __future__ import annotations

import asyncio
import json
import os
from collections.abc import Iterable
from pathlib import Path

import zenoh

from . import paths
from .config import RobotConfig
from .credentials import GUEST_PASSWORD, GUEST_USER
from .errors import ConfigError
from .runtime import run, zenoh_config
from .schemas import keys

ACL_TEMPLATE = paths.packaged("zenoh", "robot-acl.json5")


def acl_rules(owners: Iterable[tuple[str, str]]) -> str:
    """The ``access_control`` JSON5 object for (robot, user) pairs: each robot writable by its user only."""
    template = ACL_TEMPLATE.read_text()
    acls = []
    for robot, user in owners:
        text = template.replace("{robot}", robot).replace("{user}", user)
        acls.append(json.loads(zenoh.Config.from_json5(text).get_json("access_control")))  # Zenoh reads its JSON5
    rules = [rule for acl in acls for rule in acl["rules"]]
    subjects = list({s["id"]: s for acl in acls for s in acl["subjects"]}.values())  # "anyone" once
    # Zenoh lets a message through when any subject that matches its sender allows it, and a
    # subject that no deny rule covers is allowed by default. So in a lab, robot A's owner would
    # be allowed to drive robot B: each policy that applies to everyone (a subject without
    # usernames) must name the owners of the other robots too.
    owner_ids = [[s["id"] for s in acl["subjects"] if s.get("usernames")] for acl in acls]
    everyone = {s["id"] for s in subjects if not s.get("usernames")}
    policies = []
    for i, acl in enumerate(acls):
        others = [sid for j, ids in enumerate(owner_ids) if j != i for sid in ids]
        for policy in acl["policies"]:
            if everyone & set(policy["subjects"]):
                policy = {**policy, "subjects": [*policy["subjects"], *others]}
            policies.append(policy)
    return json.dumps({"enabled": True, "default_permission": "allow", "rules": rules,
                       "subjects": subjects, "policies": policies})


def router_config(config: RobotConfig, owners: list[tuple[str, str, str]] | None = None) -> zenoh.Config:
    """Zenoh config of the router; ``owners`` = (robot, user, password) for access control."""
    zc = zenoh_config(config, mode="router", listen=config.zenoh.listen)
    # Read-only admin space: who declared what (`icefloe topics -v`, `info`, `services`; icefloe/graph.py).
    zc.insert_json5("adminspace", '{"enabled": true, "permissions": {"read": true, "write": false}}')
    if owners is None and config.zenoh.access_control:
        if not config.zenoh.user:
            where = config.zenoh.credentials or "(zenoh.credentials is not set)"
            raise ConfigError(f"{config.source}: zenoh.access_control is on but there are no credentials "
                              f"at {where}: run `icefloe credentials {config.source}`")
        owners = [(config.name, config.zenoh.user, config.zenoh.password)]
    if owners:
        users = config.runtime_dir / "zenoh-users"
        users.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(users, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.writelines(f"{user}:{password}\n" for _, user, password in owners)
            f.write(f"{GUEST_USER}:{GUEST_PASSWORD}\n")
        zc.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users)))
        zc.insert_json5("access_control", acl_rules((robot, user) for robot, user, _ in owners))
    return zc


async def serve(config: RobotConfig, zc: zenoh.Config, what: str) -> None:
    session = zenoh.open(zc)
    token = session.liveliness().declare_token(keys.alive_key(config.name, "router"))
    print(f"{what} listening on {', '.join(config.zenoh.listen)}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        token.undeclare()
        session.close()


async def main(config: RobotConfig) -> None:
    acl = " with access control" if config.zenoh.access_control else ""
    await serve(config, router_config(config), f"router for {config.name!r}{acl}")


def lab_owners(lab_dir: Path) -> list[tuple[str, str, str]]:
    """(robot, user, password) of every credentials file in a folder."""
    from .credentials import read

    owners = []
    for path in sorted(lab_dir.glob("*.credentials")):
        creds = read(path)
        owners.append((creds.robot, creds.user, creds.password))
    if not owners:
        raise ConfigError(f"{lab_dir}: no *.credentials files: nothing to route for")
    return owners


if __name__ == "__main__":
    run(main, description="icefloe's Zenoh router")
