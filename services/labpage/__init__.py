"""The lab's page: the TA's emergency stop in a browser, served by the lab machine (docs/lab.md).

``python -m icefloe.services.labpage --config lab.toml`` serves, on ``[lab] page_host`` and
``page_port``, a page that lists every robot of the lab's credentials folder (and every other
robot alive on the bus), whether it is held, and what it last answered; a button stops, holds or
releases every robot at once, or one. It logs in to the lab router as the lab's TA account (the
folder's file whose robot is "*") and asks the robots as ``icefloe lab stop`` does
(`icefloe.labstop`); the page asks the same user and password (HTTP Basic).

Modules: ``roster`` (what the page shows of each robot, from the bus; no I/O), ``page`` (the TA's login and
HTTP routes, no bus), ``__main__`` (the wiring).
"""
