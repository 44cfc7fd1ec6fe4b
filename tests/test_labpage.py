"""The lab's page (services/labpage), its parts without a bus: the roster it shows and its HTTP routes,
with a stand-in for the robots' answers. Every route asks for the TA's login; ``/stop`` takes only JSON
from the page itself, checks every field before anything is asked, and names what was wrong. The
page's button on a real lab, with a real browser, is in tests/test_lab_stop.py. About 2 s."""

from __future__ import annotations

import base64
import logging
from pathlib import Path

import pytest
from aiohttp.test_utils import TestClient, TestServer

from icefloe.config import Lab, RobotConfig
from icefloe.credentials import make
from icefloe.errors import ConfigError
from icefloe.labstop import Answer
from icefloe.logs import LimitedLog
from icefloe.schemas import keys
from icefloe.schemas import messages as m
from icefloe.services.labpage.page import LabPage, Login, StopRequest, login_of
from icefloe.services.labpage.roster import MAX_ROBOTS, Roster


def basic(user: str, password: str) -> dict[str, str]:
    return {"Authorization": "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()}


def test_the_roster_lists_the_labs_robots_and_those_alive() -> None:
    roster = Roster(["p2", "p1"])
    assert [r["name"] for r in roster.to_json()] == ["p1", "p2"] and roster.known() == ["p1", "p2"]
    roster.token(keys.alive_key("p3", "hwbridge"), True)  # a robot not of the lab's folder, alive
    roster.token(keys.alive_key("p4", "odometry"), True)  # not a hwbridge: cannot stop, not listed
    roster.token(keys.alive_key("p1", "hwbridge"), True)
    assert roster.known() == ["p1", "p2", "p3"]
    rows = {r["name"]: r for r in roster.to_json()}
    assert rows["p1"]["alive"] and not rows["p2"]["alive"] and not rows["p3"]["in_folder"]
    roster.token(keys.alive_key("p3", "hwbridge"), False)
    assert roster.known() == ["p1", "p2"]  # gone, and not of the lab: no longer asked
    roster.hold(keys.key("p1", keys.HOLD), m.Hold(stamp=1, held=True, since=5, reason="see me"))
    roster.hold("icefloe/*/hw/hold", m.Hold(stamp=1, held=True))  # a wildcard names no robot
    rows = {r["name"]: r for r in roster.to_json()}
    assert rows["p1"]["held"] and rows["p1"]["reason"] == "see me" and not rows["p2"]["held"]
    roster.answered([Answer("p2", False, detail="nobody answers")])
    assert {r["name"]: r for r in roster.to_json()}["p2"]["last"]["line"] == "p2: NOT confirmed: nobody answers"
    # A flood of made-up tokens does not grow it without bound.
    for i in range(MAX_ROBOTS + 100):
        roster.token(keys.alive_key(f"fake{i}", "hwbridge"), True)
    assert len(roster.to_json()) == 2 + MAX_ROBOTS


class Robots:
    """Stands in for the robots: records what it was asked, answers each as confirmed."""

    def __init__(self) -> None:
        self.asked: list[tuple[StopRequest, list[str]]] = []

    async def __call__(self, body: StopRequest, robots: list[str]) -> list[Answer]:
        self.asked.append((body, robots))
        return [Answer(r, True, body.action == "hold", 0.03) for r in robots or ["p1", "p2"]]


@pytest.fixture
async def page() -> tuple[TestClient, Robots, Roster]:
    roster, robots = Roster(["p1", "p2"]), Robots()
    app = LabPage(Login("ta", "s3cret"), roster, robots, 1.0, LimitedLog(logging.getLogger("labpage"))).app()
    async with TestClient(TestServer(app)) as client:
        yield client, robots, roster


async def test_every_route_asks_for_the_tas_login(page) -> None:
    client, robots, _ = page
    for headers in ({}, basic("ta", "wrong"), basic("guest", "guest"), basic("p1", "s3cret"),
                    {"Authorization": "Basic !!!"}, {"Authorization": "Bearer s3cret"}):
        for method, path in (("GET", "/"), ("GET", "/lab.json"), ("POST", "/stop"), ("GET", "/static/page.js")):
            response = await client.request(method, path, headers=headers, json={"action": "stop"})
            assert response.status == 401, (headers, path)
            assert response.headers["WWW-Authenticate"].startswith("Basic realm=")
    assert robots.asked == []
    ta = basic("ta", "s3cret")
    assert "STOP every robot" in await (await client.get("/", headers=ta)).text()
    assert "fetch(\"/stop\"" in await (await client.get("/static/page.js", headers=ta)).text()
    lab = await (await client.get("/lab.json", headers=ta)).json()
    assert [r["name"] for r in lab["robots"]] == ["p1", "p2"] and lab["timeout"] == 1.0


async def test_stop_takes_json_from_the_page_itself_and_names_what_was_wrong(page) -> None:
    client, robots, roster = page
    ta = basic("ta", "s3cret")
    host = f"http://{client.host}:{client.port}"
    # A form another site posts with the TA's cached login: not JSON, or from another origin.
    response = await client.post("/stop", headers=ta, data={"action": "hold"})
    assert response.status == 415 and "application/json" in (await response.json())["message"]
    response = await client.post("/stop", headers={**ta, "Origin": "http://evil.example"}, json={"action": "hold"})
    assert response.status == 403 and "another site" in (await response.json())["message"]
    for body, wrong in (({"action": "drive"}, "action"), ({"action": "hold", "robots": ["*"]}, "name one robot"),
                        ({"action": "hold", "robots": ["p1/cmd"]}, "name one robot"),
                        ({"action": "stop", "reason": "x" * 61}, "reason"), ({"action": "stop", "v": 1}, "v"),
                        ({"robots": ["p1"]}, "action"), ("stop", "Expected `object`")):
        response = await client.post("/stop", headers={**ta, "Origin": host}, json=body)
        assert response.status == 400 and wrong in (await response.json())["message"], (body, await response.text())
    response = await client.post("/stop", headers=ta, data=b"\xff\x00 not json")
    assert response.status == 415
    response = await client.post("/stop", headers={**ta, "Content-Type": "application/json"}, data=b"\xff\x00")
    assert response.status == 400
    assert robots.asked == [], "a refused request asked the robots"

    # The page's own requests: every robot, or one, with the TA's words.
    response = await client.post("/stop", headers={**ta, "Origin": host}, json={"action": "stop"})
    done = await response.json()
    assert response.status == 200 and done["summary"] == "2 of 2 robots stopped and confirmed"
    assert [a["line"] for a in done["answers"]] == ["p1: confirmed in 30 ms", "p2: confirmed in 30 ms"]
    response = await client.post("/stop", headers=ta, json={"action": "hold", "robots": ["p2"], "reason": "see me",
                                                            "owner_may_release": True})
    assert (await response.json())["summary"] == "1 of 1 robots held stopped and confirmed"
    assert [(b.action, b.reason, b.owner_may_release, r) for b, r in robots.asked] == \
        [("stop", "", False, []), ("hold", "see me", True, ["p2"])]
    assert {r["name"]: r["last"]["held"] for r in roster.to_json()} == {"p1": False, "p2": True}


def test_the_page_starts_only_with_the_labs_folder_and_its_ta(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"lab\.folder is not set"):
        login_of(RobotConfig(name="lab", source="lab.toml"))
    make(tmp_path / "p1.credentials", "p1")
    config = RobotConfig(name="lab", lab=Lab(folder=str(tmp_path)))
    with pytest.raises(ConfigError, match=r"no TA credentials file \(robot = \"\*\""):
        login_of(config)
    make(tmp_path / "ta.credentials", "*")
    folder, ta_config, login = login_of(config)
    assert folder.robots == ["p1"] and ta_config.zenoh.user == login.user and login.password
