"""Who publishes, subscribes to and answers what on a bus: the graph `icefloe topics -v`,
`icefloe info` and `icefloe services` show, as `ros2 node info` does.

Nothing is announced for it: the robot's Zenoh router already knows every declaration of
its clients and tells through its admin space (``adminspace.permissions.read``, on in
`icefloe.router`)::

    @/<router zid>/router/publisher/icefloe/sim/odom/pose    {"clients": ["<session zid>"], ...}
    @/<router zid>/router/subscriber/icefloe/sim/**          {"clients": [...]}
    @/<router zid>/router/queryable/icefloe/sim/info         ...
    @/<router zid>/router/token/icefloe/sim/alive/odometry   ...

A session that holds the liveliness token ``icefloe/<robot>/alive/<service>`` (every `Node`
does) is named by it; other sessions (a command-line tool, a raw Zenoh program without a
token) are counted but have no name. A service in another language gets its name the same
way: by declaring that token. Publishers count only when declared (``declare_publisher``);
a bare ``session.put`` leaves no trace.
"""

from __future__ import annotations

import asyncio
import json
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Literal

import zenoh

from .schemas import keys

Kind = Literal["publisher", "subscriber", "queryable", "token"]
KINDS: tuple[Kind, ...] = ("publisher", "subscriber", "queryable", "token")


@dataclass(frozen=True)
class Declaration:
    kind: Kind
    key_expr: str
    """As declared: may hold wildcards (``icefloe/*/alive/*``)."""


@dataclass
class Graph:
    """The declarations under ``icefloe/`` that the routers report, by session."""

    by_session: dict[str, set[Declaration]] = field(default_factory=lambda: defaultdict(set))
    """Session id (zid) -> what it declared."""
    routers: int = 0
    """Routers whose admin space answered (0: closed, so nothing is known)."""

    def names(self) -> dict[str, str]:
        """Session id -> ``<robot>/<service>``, from the liveliness tokens the sessions hold."""
        out = {}
        for zid, decls in self.by_session.items():
            for d in decls:
                if d.kind == "token" and "*" not in d.key_expr:
                    robot, name = keys.split(d.key_expr)
                    if name.startswith("alive/"):
                        out[zid] = f"{robot}/{name.removeprefix('alive/')}"
        return out

    def name(self, zid: str, robot: str | None = None) -> str:
        """A session's name: the service, with its robot unless it is ``robot``; else ``(unnamed <zid[:8]>)``."""
        full = self.names().get(zid)
        if full is None:
            return f"(unnamed {zid[:8]})"
        owner, service = full.split("/", 1)
        return service if owner == robot else full

    def on(self, key_expr: str, kind: Kind) -> list[str]:
        """Sessions with a declaration of ``kind`` that reaches ``key_expr`` (wildcards intersect)."""
        want = zenoh.KeyExpr(key_expr)
        return sorted(zid for zid, decls in self.by_session.items()
                      if any(d.kind == kind and zenoh.KeyExpr(d.key_expr).intersects(want) for d in decls))

    def keys_declared(self, prefix: str) -> set[str]:
        """Concrete keys (no wildcards) declared under ``prefix`` by publishers and queryables."""
        return {d.key_expr for decls in self.by_session.values() for d in decls
                if d.kind in ("publisher", "queryable") and d.key_expr.startswith(prefix) and "*" not in d.key_expr}


def parse(replies: list[tuple[str, bytes]]) -> Graph:
    """The graph from admin-space replies (key, JSON payload)."""
    graph = Graph()
    for key, payload in replies:
        parts = key.split("/", 4)  # @, zid, router, kind, key expression
        if len(parts) < 5 or parts[2] != "router" or parts[3] not in KINDS:
            continue
        try:
            holders = json.loads(payload)
        except ValueError:
            continue
        for zid in [*holders.get("clients", []), *holders.get("peers", [])]:
            graph.by_session[zid].add(Declaration(parts[3], parts[4]))  # type: ignore[arg-type]
    return graph


async def read(session: zenoh.Session, timeout: float = 1.0) -> Graph:
    """Ask every router on the bus what is declared under ``icefloe/``."""
    def ask(selector: str) -> list[tuple[str, bytes]]:
        return [(str(r.ok.key_expr), r.ok.payload.to_bytes())
                for r in session.get(selector, timeout=timeout) if r.ok is not None]

    routers, declared = await asyncio.gather(asyncio.to_thread(ask, "@/*/router"),
                                             asyncio.to_thread(ask, f"@/*/router/*/{keys.PREFIX}/**"))
    graph = parse(declared)
    graph.routers = len(routers)
    return graph
