"""The robot's web pages: the status page at ``/`` and the old PenguinPi forms.

* ``/``: the robot's page (``static/index.html`` and ``static/page.js``, plain HTML and
  JavaScript, no build step): battery, poses, services, the camera with its markers, the
  log, a drive pad. It reads and drives the robot only through the HTTP bridge (``/bus/``,
  `bus`), as any page of a student's could; ``/page/robot.json`` tells it the robot's name
  and limits.
* ``/speed`` and ``/settings``: the old server's forms (facts §5.6), server-side HTML as
  before: ``/speed`` POSTs ``Left``, ``Right`` and ``Set`` (or ``STOP``); ``/settings``
  POSTs ``led`` (hex, the LED array) and ``led2``..``led4`` (0/1). ``kvp``, ``kvi`` and
  ``adcpole`` are the robot config's now (``[hwbridge] kp, ki``, ``[power] pole``): the
  form says so instead of setting them. ``?refresh=N`` reloads a page every N seconds,
  as the old pages did.
"""

from __future__ import annotations

import html
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from aiohttp import web

from icefloe.schemas import messages as m

from . import params
from .params import InvalidCommand

if TYPE_CHECKING:
    from .routes import Api

STATIC = Path(str(resources.files(__package__) / "static"))
"""The page's files, shipped in the wheel (docs/DEVELOPING.md)."""
HTML = "text/html"

FORM_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title} · {robot}</title>
<meta name="viewport" content="width=device-width, initial-scale=1">{refresh}
<link rel="stylesheet" href="/static/page.css"></head>
<body class="form-page"><nav><a href="/">{robot}</a> <a href="/speed">speed</a> <a href="/settings">settings</a></nav>
<h1>{title}</h1>{note}{body}</body></html>
"""


class Pages:
    """The page routes; they act through the web API's own handlers (`Api`)."""

    def __init__(self, api: Api) -> None:
        self.api = api
        self.robot = api.robot.config

    def routes(self, app: web.Application) -> None:
        app.router.add_get("/", self.index)
        app.router.add_post("/", self.motor_test)
        app.router.add_get("/page/robot.json", self.robot_json)
        app.router.add_route("GET", "/speed", self.speed)
        app.router.add_route("POST", "/speed", self.speed)
        app.router.add_route("GET", "/settings", self.settings)
        app.router.add_route("POST", "/settings", self.settings)
        app.router.add_static("/static", STATIC, append_version=False)

    def commands(self) -> set[str]:
        """Paths that change the robot (POSTs): the owner's, on a robot with access control."""
        return {"/", "/speed", "/settings"}

    async def index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def robot_json(self, request: web.Request) -> web.Response:
        """What the page needs to know that the bus does not say: the robot's name and limits."""
        c = self.robot
        return web.json_response({
            "robot": c.name,
            "deadman_s": c.hwbridge.deadman_s,
            "max_wheel_speed": c.hwbridge.max_wheel_speed,
            "track": c.geometry.track,
            "camera": {"width": c.camera.width, "height": c.camera.height},
            "car": {"wheelbase": c.car.wheelbase, "max_steer": c.car.max_steer, "steer_rate": c.car.steer_rate},
            "access_control": c.zenoh.access_control,
        })

    async def motor_test(self, request: web.Request) -> web.Response:
        """The old home page's motor test: POST ``test_l`` or ``test_r`` runs that motor at 20 for 2 s."""
        form = await request.post()
        side = "test_l" if "test_l" in form else "test_r" if "test_r" in form else None
        if side is None:
            raise InvalidCommand("motor test: POST test_l or test_r")
        speed = 20 * self.api.unit
        await self.api.robot.set_velocity(speed if side == "test_l" else 0.0,
                                          speed if side == "test_r" else 0.0, 2.0)
        raise web.HTTPSeeOther("/")

    # ------------------------------------------------------------------ the old forms

    def form_page(self, request: web.Request, title: str, body: str, note: str = "",
                  status: int = 200) -> web.Response:
        refresh = ""
        text = request.query.get("refresh", "")
        if text.isdigit() and 0 < int(text) <= 3600:
            refresh = f'\n<meta http-equiv="refresh" content="{int(text)}">'
        note_html = f'<p class="note">{html.escape(note)}</p>' if note else ""
        page = FORM_PAGE.format(title=title, robot=html.escape(self.robot.name), refresh=refresh,
                                note=note_html, body=body)
        return web.Response(text=page, content_type=HTML, charset="utf-8", status=status)

    async def speed(self, request: web.Request) -> web.Response:
        note, status = "", 200
        if request.method == "POST":
            form = await request.post()
            try:
                if "STOP" in form:
                    await self.api.robot.stop()
                    self.api.demand = [0.0, 0.0]
                    note = "stopped"
                else:
                    value = f"{form.get('Left', '')},{form.get('Right', '')}"
                    left, right = params.speeds({"value": value}, self.api.max_demand)
                    await self.api.drive(left, right)
                    note = f"driving at {left:g}, {right:g} (until the next command)"
            except InvalidCommand as exc:
                note, status = exc.message, 400
        left, right = self.api.demand
        enc = await self.api.encoders()
        body = f"""<form method="post">
<label>Left <input name="Left" type="number" min="-{self.api.max_demand}" max="{self.api.max_demand}"
 value="{left:g}"></label>
<label>Right <input name="Right" type="number" min="-{self.api.max_demand}" max="{self.api.max_demand}"
 value="{right:g}"></label>
<input type="submit" name="Set" value="Set"> <input type="submit" name="STOP" value="STOP">
</form>
<p>Speeds in firmware demand units (1 unit = {self.api.unit * 1000:.2f} mm/s). Encoders:
{"-" if enc is None else f"{enc[0]}, {enc[1]}"}.</p>"""
        return self.form_page(request, "Speed", body, note, status)

    async def settings(self, request: web.Request) -> web.Response:
        note, status = "", 200
        if request.method == "POST":
            form = await request.post()
            try:
                note = self.apply_settings({k: str(v) for k, v in form.items()})
            except InvalidCommand as exc:
                note, status = exc.message, 400
        leds = self.api.robot.leds
        dip_value = await self.api.get_dip()
        dip = "-" if dip_value is None else str(dip_value)
        boxes = "".join(
            f'<label>LED {i} <select name="led{i}"><option value="0">off</option>'
            f'<option value="1"{" selected" if leds[i] else ""}>on</option></select></label> '
            for i in (2, 3, 4))
        g = self.robot.hwbridge
        body = f"""<form method="post">
<label>LED array (hex) <input name="led" value="" placeholder="0x0000"></label>
{boxes}
<fieldset disabled><legend>in the robot config now</legend>
<label>kvp <input name="kvp" value="{g.kp:g}"></label> <label>kvi <input name="kvi" value="{g.ki:g}"></label>
<label>adcpole <input name="adcpole" value="{self.robot.power.pole:g}"></label></fieldset>
<input type="submit" value="Set">
</form>
<p>DIP switch: {dip}. S4 presses since the last read: {self.api.s4_presses}.</p>"""
        return self.form_page(request, "Settings", body, note, status)

    def apply_settings(self, form: dict[str, str]) -> str:
        """Check every field first (nothing is sent if one is bad), then set; what was done."""
        done: list[str] = []
        mask = None
        if text := form.get("led", "").strip():
            hex_text = text if text.lower().startswith(("0x", "0b")) else "0x" + text  # the old form: hex, no 0x
            mask = params.integer({"led": hex_text}, "led", "Bad value", 0, 0xFFFF, any_base=True)
        leds = {i: params.integer(form, f"led{i}", "Bad led value", 0, 1) for i in (2, 3, 4)
                if form.get(f"led{i}", "").strip()}
        config_only = [k for k in ("kvp", "kvi", "adcpole") if form.get(k, "").strip()]
        if mask is not None:
            self.api._ledarray.put(m.LedArray(mask=mask))
            done.append(f"LED array {mask:#06x}")
        for led, on in leds.items():
            self.api.robot.leds[led] = bool(on)
            done.append(f"LED {led} {'on' if on else 'off'}")
        if config_only:
            done.append(f"not set: {', '.join(config_only)} (in the robot config now: [hwbridge] kp and ki, "
                        "[power] pole)")
        return "; ".join(done) or "nothing to set"

