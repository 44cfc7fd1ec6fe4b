"""`./deploy/up.sh` and the Rerun viewer: it opens on a display (Xvfb here) whatever PATH is, and
without a display `up` says in one line how to look, and nothing restarts in a loop."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import ROOT, processes_naming, robot_config
from test_cli import wait_alive

from icefloe.services.viz import viewer

ViewerClient = pytest.importorskip("rerun.experimental").ViewerClient

VIEWER_PORT = 9876
"""The native viewer's default port (`icefloe viz --grpc-port`), the one `up` uses."""


def plain_env(**extra: str) -> dict[str, str]:
    """The environment of a new terminal: the venv not activated, no display unless given."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "VIRTUAL_ENV")}
    env["PATH"] = "/usr/local/bin:/usr/bin:/bin"
    return {**env, **extra}


class Up:
    """`./deploy/up.sh CONFIG` as a student runs it, its output in a file."""

    def __init__(self, cfg: Path, env: dict[str, str], log: Path) -> None:
        self.log = log
        self._out = open(log, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(["./deploy/up.sh", str(cfg)], cwd=ROOT, env=env, stdout=self._out,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_for(self, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.text:
            assert self.proc.poll() is None, f"up.sh exited {self.proc.returncode}:\n{self.text}"
            assert time.monotonic() < deadline, f"{text!r} not in up.sh's output within {timeout} s:\n{self.text}"
            time.sleep(0.2)

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            raise
        finally:
            self._out.close()


def viz_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("[viz ")]


def test_the_viewer_is_the_one_installed_with_this_python(monkeypatch) -> None:
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    found = Path(viewer.executable())
    assert found.name == "rerun" and found.is_relative_to(Path(sys.executable).parent.parent)  # in the venv
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert "no display here" in (viewer.display_problem() or "")


def test_viz_without_a_display_says_how_to_look_in_one_line() -> None:
    res = subprocess.run([sys.executable, "-m", "icefloe.cli", "viz"], env=plain_env(), capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr, res.stderr
    assert "no display here" in res.stderr and "icefloe viz --serve" in res.stderr


@pytest.mark.slow
@pytest.mark.timeout(300)  # the first run of up.sh installs the viz extra
def test_up_without_a_display_says_how_to_look_and_runs(tmp_path: Path) -> None:
    cfg = robot_config(tmp_path, "nodisplay", 'services = ["info"]')
    up = Up(cfg, plain_env(), tmp_path / "up.log")
    try:
        up.wait_for("[up", timeout=240)
        wait_alive(cfg, "info", timeout=30)
        time.sleep(2.0)
    finally:
        assert up.stop() == 0, up.text
    hints = [line for line in up.text.splitlines() if "no viewer" in line]
    assert len(hints) == 1 and "icefloe viz --serve" in hints[0] and "--connect" in hints[0], up.text
    assert not viz_lines(up.text) and "restarting" not in up.text and "Traceback" not in up.text, up.text


@pytest.fixture(scope="module")
def xvfb() -> Iterator[str]:
    """A virtual X display (Debian's xvfb; tests/run.sh installs it when run as root)."""
    if not any(Path(d, "Xvfb").exists() for d in ("/usr/bin", "/usr/local/bin")):
        pytest.skip("Xvfb is not installed: apt-get install xvfb mesa-vulkan-drivers (tests/run.sh does it as root)")
    read, write = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        pytest.fail("Xvfb did not start")
    yield f":{number}"
    proc.terminate()
    proc.wait(10)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_up_opens_the_viewer_on_a_display_whatever_path_is(tmp_path: Path, xvfb: str) -> None:
    if viewer.listening(VIEWER_PORT):
        pytest.skip(f"a Rerun viewer already listens on port {VIEWER_PORT} here (another run of this test?)")
    cfg = robot_config(tmp_path, "display", 'services = ["info"]')
    up = Up(cfg, plain_env(DISPLAY=xvfb), tmp_path / "up.log")
    windows: list[int] = []
    try:
        up.wait_for("showing robot", timeout=240)
        windows = [p for p in processes_naming(f"--port {VIEWER_PORT}") if "rerun" in Path(f"/proc/{p}/cmdline")
                   .read_text()]
        assert windows, f"no viewer process:\n{up.text}"
        # The viewer shows the default blueprint: the robot's map, its plots (asked of the viewer itself).
        robot = re.search(r"showing robot '([^']+)'", up.text).group(1)  # type: ignore[union-attr]
        layout = json.dumps(ViewerClient.connect(f"rerun+http://127.0.0.1:{VIEWER_PORT}/proxy").get_blueprint()
                            .blueprint)
        assert f"{robot}: map (m)" in layout and "wheel speed (m/s)" in layout and "log" in layout, layout[:2000]
        time.sleep(5.0)  # viz stays up, streaming to the viewer; nothing restarts
        assert all(Path(f"/proc/{p}").exists() for p in windows), up.text
        assert "exited" not in up.text and "restarting" not in up.text, up.text
        for pid in windows:  # the student closes the window: viz ends, and is not restarted
            os.kill(pid, signal.SIGTERM)
        up.wait_for("the viewer was closed", timeout=20)
        up.wait_for("not restarting it", timeout=20)
        time.sleep(2.0)
        assert not viewer.listening(VIEWER_PORT), "a viewer was opened again"
    finally:
        code = up.stop()
        for pid in windows:
            if Path(f"/proc/{pid}").exists():
                os.kill(pid, signal.SIGKILL)
    assert code == 0, up.text
    assert viz_lines(up.text) and "Traceback" not in up.text, up.text
