"""The lab's page over HTTP: the routes, the TA's login, the checks of every request. No bus:
the service (``__main__``) hands it the roster and the function that asks the robots.

    GET  /            the page (static/index.html, page.js: plain HTML and JavaScript)
    GET  /lab.json    every robot: alive, held, what it last answered (`roster.Roster`)
    POST /stop        {"action": "stop" | "hold" | "release", "robots": [...] (none: every robot),
                       "reason": "...", "owner_may_release": false} -> every robot's answer

Every route asks for the TA's user and password (HTTP Basic; 401 with a challenge otherwise).
A browser sends a login it has cached to every page of the site, also for a form that another
site posts there; so ``/stop`` takes JSON only (a cross-site form cannot send it without the
browser asking first, and we never say yes) and, when the browser names the page that sent the
request (``Origin``), only from this page itself.
"""

from __future__ import annotations

import base64
import hmac
import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import msgspec
from aiohttp import web

from icefloe import labstop
from icefloe.config import RobotConfig
from icefloe.errors import ConfigError
from icefloe.labstop import Answer, check_names, summary
from icefloe.logs import LimitedLog

from .roster import Roster

STATIC = Path(str(resources.files(__package__) / "static"))
"""The page's files, shipped in the wheel (docs/DEVELOPING.md)."""
MAX_BODY = 64 * 1024
"""Largest request body taken, bytes (a request naming every robot of a big lab fits)."""


class StopRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The body of ``POST /stop``."""

    action: Literal["stop", "hold", "release"]
    robots: Annotated[list[str], msgspec.Meta(max_length=1000)] = []
    """Robot names; none: every robot of the lab and every other one alive."""
    reason: Annotated[str, msgspec.Meta(max_length=60)] = ""
    owner_may_release: bool = False


Stopper = Callable[[StopRequest, list[str]], Awaitable[list[Answer]]]
"""Asks ``robots`` (the request's, or every known one) and returns their answers."""


@dataclass(frozen=True)
class Login:
    """The TA's user and password, as HTTP Basic checks them."""

    user: str
    password: str

    def accepts(self, header: str | None) -> bool:
        scheme, _, encoded = (header or "").partition(" ")
        try:
            given = base64.b64decode(encoded.strip(), validate=True)
        except ValueError:
            given = b""
        user, colon, password = given.partition(b":")
        # Both parts compared in constant time, always: the answer's timing tells nothing.
        right = hmac.compare_digest(user, self.user.encode()) & hmac.compare_digest(password, self.password.encode())
        return scheme.lower() == "basic" and bool(colon) and right


def login_of(config: RobotConfig) -> tuple[labstop.LabFolder, RobotConfig, Login]:
    """The lab's folder, the config logged in as its TA, and the TA's login for the page;
    `ConfigError` (one line) for a lab config the page cannot work with."""
    if not config.lab.folder:
        raise ConfigError(f"{config.source}: lab.folder is not set: the page needs the lab's credentials folder "
                          "(its robots, and the TA's credentials file)")
    folder = labstop.lab_folder(Path(config.lab.folder), config.name)
    if not folder.ta:
        raise ConfigError(f"{config.lab.folder}: no TA credentials file (robot = \"*\", docs/lab.md): the page "
                          "logs in as the lab's TA")
    ta_config, _ = labstop.ta_config(config, folder)
    return folder, ta_config, Login(ta_config.zenoh.user, ta_config.zenoh.password)


def json_error(status: int, message: str, headers: dict[str, str] | None = None) -> web.Response:
    return web.Response(status=status, body=json.dumps({"message": message}).encode(),
                        content_type="application/json", headers=headers)


class LabPage:
    """The routes of the lab's page."""

    def __init__(self, login: Login, roster: Roster, stopper: Stopper, timeout: float, limited: LimitedLog) -> None:
        self.login = login
        self.roster = roster
        self.stopper = stopper
        self.timeout = timeout
        self.limited = limited

    def app(self) -> web.Application:
        app = web.Application(middlewares=[self.ta_only], client_max_size=MAX_BODY)
        app.router.add_get("/", self.index)
        app.router.add_get("/lab.json", self.lab_json)
        app.router.add_post("/stop", self.stop)
        app.router.add_static("/static", STATIC, append_version=False)
        return app

    @web.middleware
    async def ta_only(self, request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
                      ) -> web.StreamResponse:
        if not self.login.accepts(request.headers.get("Authorization")):
            if "Authorization" in request.headers:
                self.limited.warning("wrong login", "%s from %s: wrong user or password, refused", request.path,
                                     request.remote)
            return json_error(401, "the lab's page: the TA's user and password (HTTP Basic)",
                              {"WWW-Authenticate": 'Basic realm="icefloe lab", charset="UTF-8"'})
        return await handler(request)

    async def index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def lab_json(self, request: web.Request) -> web.Response:
        return web.json_response({"robots": self.roster.to_json(), "timeout": self.timeout})

    async def stop(self, request: web.Request) -> web.Response:
        if request.content_type != "application/json":
            return self.refuse(request, 415, f"/stop takes application/json, not {request.content_type!r}")
        origin = request.headers.get("Origin")
        if origin is not None and origin not in (f"http://{request.host}", f"https://{request.host}"):
            return self.refuse(request, 403, f"/stop from another site ({origin}) refused")
        try:
            body = msgspec.json.decode(await request.read(), type=StopRequest)
            robots = check_names(body.robots)
        except (msgspec.DecodeError, msgspec.ValidationError, ConfigError) as exc:
            return self.refuse(request, 400, f"/stop: {exc}")
        answers = await self.stopper(body, robots)
        self.roster.answered(answers)
        return web.json_response({"answers": [{"robot": a.robot, "confirmed": a.confirmed, "held": a.held,
                                               "ms": None if a.seconds is None else round(a.seconds * 1e3, 1),
                                               "line": a.line()} for a in answers],
                                  "summary": summary(answers, body.action) if answers else "no robot to ask"})

    def refuse(self, request: web.Request, status: int, message: str) -> web.Response:
        self.limited.warning(f"refused {status}", "%s from %s: %s", request.path, request.remote, message)
        return json_error(status, message)
