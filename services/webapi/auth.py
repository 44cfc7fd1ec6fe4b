"""Who may change the robot over HTTP: the robot's owner, with HTTP Basic authentication.

On a robot with ``[zenoh] access_control = true``, every route that changes anything asks
for the robot's own Zenoh user and password (from its credentials file): the same people
who may command it over Zenoh. Read-only routes stay open, as Zenoh lets the read-only
``guest`` watch every robot. Without access control (the simulated robot) nothing is asked.
The HTTP bridge (``/bus/``, `bus`) asks Zenoh's own rules instead, for the user a request
logs in as (`Login.user_of`): the owner, or the guest (also when it gives no login).

HTTP Basic is what the old clients send without a change (docs/webapi.md):

* ``pibot_client.py`` (Python ``requests``): ``PiBot("penguin1:<password>@192.168.1.23")``
  makes its URLs ``http://penguin1:<password>@192.168.1.23:8080/...``, and ``requests``
  sends the user and password from the URL with every request.
* ``PiBot.m`` (MATLAB ``webread``): ``pb.webopt = weboptions("Timeout", 5, "Username", ...,
  "Password", ...)``. MATLAB R2019b to R2025b sends them only after a 401 answer that asks
  for Basic authentication (``WWW-Authenticate: Basic``), so every 401 here carries one.
"""

from __future__ import annotations

import base64
import hmac
import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from aiohttp import web

from icefloe.credentials import GUEST_PASSWORD, GUEST_USER
from icefloe.logs import LimitedLog

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def _is(given: bytes, expected: str) -> bool:
    return hmac.compare_digest(given, expected.encode())


@dataclass(frozen=True)
class Login:
    """The robot's own Zenoh user and password, as HTTP Basic checks them."""

    user: str
    password: str
    robot: str
    limited: LimitedLog
    """Where a wrong login is said (a few lines a second, then a count)."""

    @property
    def challenge(self) -> dict[str, str]:
        return {"WWW-Authenticate": f'Basic realm="icefloe robot {self.robot}", charset="UTF-8"'}

    def user_of(self, request: web.Request) -> str | None:
        """The Zenoh user a request logs in as: the owner's, ``guest`` (given, or no login at
        all), or None for a wrong user or password (one rate-limited line)."""
        header = request.headers.get("Authorization")
        if header is None:
            return GUEST_USER
        scheme, _, encoded = header.partition(" ")
        try:
            given = base64.b64decode(encoded.strip(), validate=True)
        except ValueError:
            given = b""
        login, colon, secret = given.partition(b":")
        # Compare in constant time, both parts always, so the answer's timing tells nothing.
        owner = _is(login, self.user) & _is(secret, self.password)
        guest = _is(login, GUEST_USER) & _is(secret, GUEST_PASSWORD)
        if scheme.lower() == "basic" and colon:
            if owner:
                return self.user
            if guest:
                return GUEST_USER
        self.limited.warning("wrong login", "%s from %s: wrong user or password, refused", request.path,
                             request.remote)
        return None

    def refusal(self, request: web.Request) -> web.Response:
        """401 asking for the owner's login (with the challenge MATLAB waits for)."""
        message = f"{request.path} changes robot {self.robot}: give its user and password (HTTP Basic)"
        return web.Response(status=401, body=json.dumps({"message": message}).encode(),
                            content_type="application/json", headers=self.challenge)


def owner_only(needs_owner: Callable[[web.Request], bool], login: Login) -> Callable[..., Awaitable]:
    """aiohttp middleware: requests for which ``needs_owner`` is true need the owner's login."""

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        if not needs_owner(request):
            return await handler(request)
        if "Authorization" in request.headers and login.user_of(request) == login.user:
            return await handler(request)
        return login.refusal(request)

    return middleware
