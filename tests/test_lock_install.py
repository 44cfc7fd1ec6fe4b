"""The robot install from a wheelhouse (``deploy/up.sh ROBOT --install --wheelhouse=DIR``, issue 33):
refused in one line, before anything changes, unless DIR holds the lock's file of every package the
install takes on this machine. Checked here on small folders made up for each test, so that every run
tests the refusal; tests/test_box.py refuses a real wheelhouse in a booted Debian.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from icefloe import deploy, lock
from icefloe.errors import ConfigError

LOCKED = {"build": {"pip": "26.3"}, "robot": {"pyserial": "3.5", "smbus2": "0.6.1"}}
"""The made-up lock: its exports (build.txt, robot.txt) and the version of each package in them."""
ELSEWHERE = "luma-core==2.6.0 ; platform_machine == 'no-such-machine' --hash=sha256:" + "0" * 64
"""A pin for a machine this is not: the install takes nothing of it here, so needs no file of it."""


def wheel(folder: Path, name: str, version: str, content: bytes | None = None) -> Path:
    """A file named as a wheel of ``name`` ``version`` (its bytes are all the check reads: the hash)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}-{version}-py3-none-any.whl"
    path.write_bytes(content if content is not None else f"{name} {version}".encode())
    return path


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    """A checkout whose lock (deploy/requirements/) lists exactly the files of `wheelhouse`."""
    requirements = tmp_path / "src" / "deploy" / "requirements"
    requirements.mkdir(parents=True)
    for export, packages in LOCKED.items():
        made = {n: wheel(tmp_path / "made", n, v) for n, v in packages.items()}
        lines = [f"{n}=={v} \\\n    --hash=sha256:{sha256(made[n])}\n" for n, v in packages.items()]
        if export == "robot":
            lines.append(ELSEWHERE + "\n")
        (requirements / f"{export}.txt").write_text("# made up for a test\n" + "".join(lines))
    return tmp_path / "src"


@pytest.fixture
def wheelhouse(tmp_path: Path) -> Path:
    """A copy of every file the made-up lock lists for this machine (`wheel` makes the same bytes again)."""
    folder = tmp_path / "wheels"
    for packages in LOCKED.values():
        for name, version in packages.items():
            wheel(folder, name, version)
    return folder


def refusal(checkout: Path, wheelhouse: Path) -> str:
    with pytest.raises(ConfigError) as refused:
        deploy.check_wheelhouse(str(checkout), "robot", wheelhouse)
    return str(refused.value)


def test_the_locks_files_are_accepted(checkout: Path, wheelhouse: Path) -> None:
    deploy.check_wheelhouse(str(checkout), "robot", wheelhouse)  # (no pin for another machine is wanted)


def test_a_file_of_another_version_is_refused_in_one_line_naming_the_package(checkout: Path,
                                                                             wheelhouse: Path) -> None:
    (wheelhouse / "pyserial-3.5-py3-none-any.whl").unlink()
    wheel(wheelhouse, "pyserial", "3.4")
    said = refusal(checkout, wheelhouse)
    assert "\n" not in said
    assert "pyserial 3.5: pyserial-3.4-py3-none-any.whl is not a file the lock lists" in said, said
    assert "smbus2" not in said and "pip " not in said, said


def test_a_missing_file_is_refused_naming_the_package(checkout: Path, wheelhouse: Path) -> None:
    (wheelhouse / "pip-26.3-py3-none-any.whl").unlink()  # build.txt's pins are the install's too
    said = refusal(checkout, wheelhouse)
    assert f"pip 26.3: no file in {wheelhouse}" in said and "\n" not in said, said


def test_a_file_of_the_locks_version_built_again_is_refused(checkout: Path, wheelhouse: Path) -> None:
    wheel(wheelhouse, "smbus2", "0.6.1", b"the same name, other bytes")
    assert "smbus2 0.6.1: smbus2-0.6.1-py3-none-any.whl is not a file the lock lists" in refusal(checkout, wheelhouse)


def test_a_wheel_the_lock_lists_for_another_machine_is_refused(tmp_path: Path, checkout: Path,
                                                              wheelhouse: Path) -> None:
    # The lock lists every machine's files: a wheelhouse downloaded on a laptop for a Pi (or the other way)
    # passes a hash check, and pip would fail half-way through the install.
    foreign = wheelhouse / "smbus2-0.6.1-cp311-cp311-manylinux_2_17_s390x.whl"
    (wheelhouse / "smbus2-0.6.1-py3-none-any.whl").rename(foreign)
    lines = (checkout / "deploy/requirements/robot.txt").read_text()
    (checkout / "deploy/requirements/robot.txt").write_text(lines.replace(
        "smbus2==0.6.1 \\\n", f"smbus2==0.6.1 \\\n    --hash=sha256:{sha256(foreign)} \\\n"))
    assert "smbus2 0.6.1: smbus2-0.6.1-cp311-cp311-manylinux_2_17_s390x.whl is for another machine or Python" \
        in refusal(checkout, wheelhouse)
    locked = lock.pins(["build", "robot"], directory=checkout / "deploy/requirements")
    assert lock.wheelhouse_problems(wheelhouse, locked) == []  # (the box's check, for another machine: no tags)


def test_no_such_folder_is_refused(checkout: Path, tmp_path: Path) -> None:
    assert f"{tmp_path / 'nowhere'}: no such folder" in refusal(checkout, tmp_path / "nowhere")


def test_the_install_refuses_before_it_plans_anything(checkout: Path, wheelhouse: Path, monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    (wheelhouse / "smbus2-0.6.1-py3-none-any.whl").unlink()

    def no_plan(*_: object, **__: object) -> None:
        raise AssertionError("the install made a plan with a wheelhouse that is not the lock's")

    monkeypatch.setattr(deploy, "install_plan", no_plan)  # (as root, a plan would change this machine)
    status = deploy.main(["install", "penguin1", "--no-boot-config", "--source", str(checkout),
                          "--wheelhouse", str(wheelhouse)])
    out, err = capsys.readouterr()
    assert status == 78 and out == "", (status, out)
    assert err.count("\n") == 1 and err.startswith(f"icefloe install: --wheelhouse {wheelhouse}: "), err
    assert "smbus2 0.6.1: no file in" in err, err


def test_the_real_lock_names_every_package_an_empty_folder_lacks(tmp_path: Path) -> None:
    locked = lock.pins(["build", "robot"])
    problems = lock.wheelhouse_problems(tmp_path, locked)
    assert [p.split(":")[0] for p in problems] == [f"{n} {pin.version}" for n, pin in sorted(locked.items())]
