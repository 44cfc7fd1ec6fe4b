"""The PenguinPi web API, kept alive on icefloe: an HTTP gateway onto the bus.

The old robot served a small HTTP API (``ppweb.py``, port 8080) that the
PenguinPi clients (``pibot_client.py``, ``PiBot.m``) use. This service serves the
same routes, bodies and content types, and turns each request into bus messages
through `icefloe.client.AsyncRobot`. Routes and deliberate differences:
``docs/webapi.md``.

Modules: ``params`` (query-string parsing and checks, no I/O), ``routes`` (the
HTTP handlers), ``__main__`` (the service).
"""
