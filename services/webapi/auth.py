"""Who may change the robot over HTTP: the robot's owner, with HTTP Basic authentication.

On a robot with ``[zenoh] access_control = true``, every route that changes anything asks
for the robot's own Zenoh user and password (from its credentials file): the same people
who may command it over Zenoh. Read-only routes stay open, as Zenoh lets the read-only
``guest`` watch every robot. Without access control (the simulated robot) nothing is asked.

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
import logging
from collections.abc import Awaitable, Callable, Collection

from aiohttp import web

from icefloe.runtime import LimitedLog

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def owner_only(paths: Collection[str], user: str, password: str, robot: str) -> Callable[..., Awaitable]:
    """aiohttp middleware: requests for ``paths`` need ``user`` and ``password`` (HTTP Basic)."""
    realm = f"icefloe robot {robot}"
    challenge = {"WWW-Authenticate": f'Basic realm="{realm}", charset="UTF-8"'}
    wrong = LimitedLog(logging.getLogger("icefloe.webapi"))

    def matches(header: str) -> bool:
        """``Authorization: Basic base64(user:password)`` (RFC 7617) with our user and password."""
        scheme, _, encoded = header.partition(" ")
        try:
            given = base64.b64decode(encoded.strip(), validate=True)
        except ValueError:
            return False
        login, colon, secret = given.partition(b":")
        # Compare in constant time, both parts always, so the answer's timing tells nothing.
        same_user = hmac.compare_digest(login, user.encode())
        same_password = hmac.compare_digest(secret, password.encode())
        return scheme.lower() == "basic" and bool(colon) and same_user and same_password

    @web.middleware
    async def middleware(request: web.Request, handler: Handler) -> web.StreamResponse:
        if request.path not in paths:
            return await handler(request)
        header = request.headers.get("Authorization")
        if header is not None and matches(header):
            return await handler(request)
        if header is not None:  # no header is how MATLAB starts: not worth a line
            wrong.warning(f"{request.path} from {request.remote}: wrong user or password, refused")
        message = f"{request.path} changes robot {robot}: give its user and password (HTTP Basic)"
        return web.Response(status=401, body=json.dumps({"message": message}).encode(),
                            content_type="application/json", headers=challenge)

    return middleware
