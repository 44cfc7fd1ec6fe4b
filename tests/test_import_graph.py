"""Who may import what (docs/DEVELOPING.md, "Where things go"), checked on every .py file's imports.

* Nothing imports a service's ``__main__``: a ``__main__`` is a service's wiring, and nothing else.
* A service imports the library (``icefloe.*`` outside ``icefloe.services``) and its own package,
  never another service's: what two services share lives in the library, so a service can be
  replaced, or run, without another's code and its dependencies.
* The library's core (``icefloe/`` but the command-line front ends, ``schemas/``, ``sim/``) imports
  no service at all: services build on it, not the other way round.
* A test, benchmark, example or tool imports a service's modules only as that service's own test:
  its file is named for the service, or `OWN` names the services it tests (and why).

The imports are read with `ast` (also those inside functions), relative ones resolved.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

from conftest import ROOT

PACKAGES = {"icefloe": "icefloe", "schemas": "icefloe.schemas", "services": "icefloe.services",
            "sim": "icefloe.sim", "deploy": "icefloe.share", "gateware": "icefloe.gateware"}
"""Folder of the repository -> the package it installs as (pyproject.toml)."""
FRONT_ENDS = ("icefloe/cli/", "icefloe/launcher.py", "deploy/")
"""The command that starts, checks and shows services (its verbs front one service each), and the
deployment tools: they may import a service's modules (never its ``__main__``)."""
OWN: dict[str, tuple[set[str], str]] = {
    "bench/hostile_input.py": ({"webapi"}, "measures the web API's HTTP keep-alive among the hostile inputs"),
    "tests/test_hostile.py": ({"webapi"}, "checks the web API's HTTP keep-alive among the hostile inputs"),
    "bench/lab_load.py": ({"camera"}, "stands in for a robot's camera with the camera's own detector and JPEGs"),
    "bench/overhead_localizer.py": ({"extloc"}, "the overhead localizer is the extloc service"),
    "bench/planner.py": ({"planner", "follower"}, "planning and following measured together"),
    "tests/test_planning.py": ({"planner", "follower"}, "the planner's and the follower's maths"),
    "tests/test_planning_sim.py": ({"follower"}, "the follower's maths on the simulated robot"),
    "bench/record_replay.py": ({"hwbridge"}, "reads hwbridge's cycle state while recording"),
    "bench/sim_profiles.py": ({"follower"}, "the follower's cross-track error, by the follower's own projection"),
    "bench/stops.py": ({"hwbridge"}, "hwbridge's stops"),
    "bench/timed_motion_model.py": ({"hwbridge", "webapi"}, "a timed motion: the web API's timing, hwbridge's "
                                    "profile, slew and dither, on the firmware model"),
    "tests/test_timed_motion.py": ({"webapi"}, "the web API's timing of a timed motion, on the simulated robot"),
    "tests/test_timed_motion_model.py": ({"webapi"}, "the web API's timing of a timed motion, on the firmware model"),
    "tests/test_gateware_loop.py": ({"hwbridge"}, "hwbridge's cycle against the gateware"),
    "tests/test_doctor.py": ({"hwbridge"}, "the real-time state of hwbridge's cycle that the doctor reports"),
    "tests/test_camera_http.py": ({"webapi"}, "the web API's camera routes"),
    "tests/test_marker_blocks.py": ({"camera"}, "the camera's detector on marker blocks"),
    "tests/test_slam_maths.py": ({"slam", "mapper"}, "SLAM's and the map maker's maths"),
    "tests/test_bag.py": ({"viz"}, "viz's demo robot's messages, recorded"),
    "tests/test_bag_cli.py": ({"viz"}, "viz's demo robot recorded, and the recording viz makes of it"),
    "tests/test_security.py": ({"viz"}, "what a viz recording holds"),
    "tests/test_lab_stop.py": ({"oled"}, "the OLED frame a held robot shows, drawn by the OLED's own screens"),
    "tests/test_viewer.py": ({"viz"}, "viz's viewer"),
    "tools/page_screenshot.py": ({"viz"}, "viz's viewer"),
}


def module_name(path: Path) -> str | None:
    """The module a file of the repository installs as, or None (tests, benches: not installed)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] not in PACKAGES:
        return None
    parts = [*PACKAGES[parts[0]].split("."), *parts[1:]]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


FOLDERS = (*PACKAGES, "tests", "bench", "examples", "tools")
"""Where the repository's Python is (not the .venv: walking it would take most of the time)."""


def python_files() -> Iterator[Path]:
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if not {"node_modules", "__pycache__"} & set(path.relative_to(ROOT).parts):
                yield path


def imports(path: Path, me: str | None = None) -> Iterator[str]:
    """Every module ``path`` imports (``from a import b`` yields a.b too: b may be a module);
    ``me``: the module it is (default: where it is in the repository), for relative imports."""
    me = me or module_name(path)
    package = (me.split(".") if path.name == "__init__.py" else me.split(".")[:-1]) if me else []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
            yield base
            yield from (f"{base}.{alias.name}" for alias in node.names)


def service_of(module: str) -> str | None:
    """``icefloe.services.camera.sources`` -> "camera"."""
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[:2] == ["icefloe", "services"] else None


def refusal(rel: str, module: str) -> str | None:
    """Why the file ``rel`` may not import ``module`` (a service's), or None if it may."""
    service = service_of(module)
    own = rel.split("/")[1] if rel.startswith("services/") and rel.count("/") > 1 else None
    if module.endswith(".__main__"):
        return "a __main__ is its service's wiring; put what it shares in a module of the service (or the library)"
    if own is not None:
        return None if service == own else (f"a service imports the library and its own package only; move what "
                                            f"{own} and {service} share into icefloe/")
    if rel.startswith(("icefloe/", "schemas/", "sim/")) and not rel.startswith(FRONT_ENDS):
        return "the library imports no service; move what it needs into the library"
    if rel.startswith(("tests/", "bench/", "examples/", "tools/")):
        words = set(Path(rel).stem.removeprefix("test_").split("_"))
        if service not in words and service not in OWN.get(rel, (set(), ""))[0]:
            return (f"only {service}'s own tests (named for it, or listed in OWN with why) import its modules; "
                    "a helper they share goes in the library")
    return None


def problems() -> list[str]:
    found = []
    for path in python_files():
        rel = path.relative_to(ROOT).as_posix()
        said: list[str] = []
        for module in sorted(set(imports(path))):
            if service_of(module) is None or any(module.startswith(f"{m}.") for m in said):
                continue  # (``from a import b``: a is said, a.b is not said again)
            if why := refusal(rel, module):
                found.append(f"{rel} imports {module}: {why}")
                said.append(module)
    return found


def test_no_module_imports_a_main_or_another_services_code() -> None:
    found = problems()
    assert not found, "\n".join(found)


def test_the_table_of_own_tests_names_files_that_exist_and_need_it() -> None:
    for rel, (services, why) in OWN.items():
        path = ROOT / rel
        assert path.is_file(), f"OWN names {rel}, which is gone"
        imported = {service_of(module) for module in imports(path)} - {None}
        assert services <= imported, f"OWN: {rel} imports nothing of {sorted(services - imported)} any more"
        assert why, rel


def test_the_checker_sees_a_main_a_neighbour_and_a_relative_import(tmp_path) -> None:
    """The checker itself, on the imports it must catch (written the ways code writes them)."""
    source = ("from icefloe.services.camera.__main__ import make_detector\n"
              "def later():\n    from ..camera import sources\n"
              "import icefloe.services.hwbridge.ordering\n")
    path = tmp_path / "probe.py"
    path.write_text(source)
    found = {m for m in imports(path, "icefloe.services.follower.probe") if service_of(m)}
    assert {"icefloe.services.camera.__main__", "icefloe.services.camera.sources",
            "icefloe.services.hwbridge.ordering"} <= found
