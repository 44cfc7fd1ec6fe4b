"""Course clients as their courses publish them, loaded unchanged for tests.

A course's client (the module its students import to drive a PenguinPi) is another project's code:
it is not copied into this repository. A test names the file by repository, commit, path and
SHA-256, and `load` finds that exact file, in this order:

1. ``$ICEFLOE_COURSE_CLIENTS/<owner>+<name>/<path>``: a folder of files fetched beforehand;
2. a git mirror of the repository, ``$ICEFLOE_COURSE_MIRRORS/<owner>+<name>/repo`` (default
   ``/work/.mirror``, where this project's build machine keeps them): ``git show <commit>:<path>``;
3. ``https://raw.githubusercontent.com/<owner>/<name>/<commit>/<path>``, kept in
   ``~/.cache/icefloe/course-clients/``.

A file whose hash differs is refused (the test fails: someone changed the course's code); when no
place has the file (no mirror, no network), the test is skipped and says so.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import subprocess
import types
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import pytest


@dataclass(frozen=True)
class CourseFile:
    repo: str
    """owner/name on GitHub."""
    commit: str
    path: str
    sha256: str

    @property
    def folder(self) -> str:
        return self.repo.replace("/", "+")


ECE4078_2023_PIBOT = CourseFile(
    repo="tianleimin/ECE4078_Lab_2023",  # Monash ECE4078 (Intelligent Robotics) labs, 2023
    commit="c8135108d548e4eae151d3e5ed0e4ec10ce2a833",
    path="Week01-02/util/pibot.py",  # class PenguinPi(ip, port): set_velocity, get_image
    sha256="2f6514d9c7c8b05577a0ba7d1fb125a37c2ad7180908685bb3ecc54731426377",
)


def _from_folder(course: CourseFile) -> bytes | None:
    root = os.environ.get("ICEFLOE_COURSE_CLIENTS")
    path = Path(root) / course.folder / course.path if root else None
    return path.read_bytes() if path is not None and path.is_file() else None


def _from_mirror(course: CourseFile) -> bytes | None:
    repo = Path(os.environ.get("ICEFLOE_COURSE_MIRRORS", "/work/.mirror")) / course.folder / "repo"
    if not repo.is_dir():
        return None
    shown = subprocess.run(["git", "--git-dir", str(repo), "show", f"{course.commit}:{course.path}"],
                           capture_output=True, timeout=30)
    return shown.stdout if shown.returncode == 0 else None


def _from_github(course: CourseFile) -> bytes | None:
    cache = Path.home() / ".cache" / "icefloe" / "course-clients" / course.folder / course.commit / course.path
    if cache.is_file():
        return cache.read_bytes()
    url = f"https://raw.githubusercontent.com/{course.repo}/{course.commit}/{course.path}"
    try:
        with urllib.request.urlopen(url, timeout=10) as answer:
            data = answer.read()
    except OSError:
        return None
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_bytes(data)
    return data


def source(course: CourseFile) -> bytes:
    """The course's file, byte for byte; the test is skipped when no place has it."""
    for find in (_from_folder, _from_mirror, _from_github):
        data = find(course)
        if data is not None:
            digest = hashlib.sha256(data).hexdigest()
            assert digest == course.sha256, (f"{course.repo} {course.path} at {course.commit[:8]} "
                                             f"({find.__name__}): SHA-256 {digest}, not {course.sha256}")
            return data
    pytest.skip(f"{course.repo}'s {course.path} is not here: no $ICEFLOE_COURSE_CLIENTS folder, no mirror, "
                "no network (see tests/course_clients.py)")


def load(course: CourseFile, tmp: Path, name: str) -> types.ModuleType:
    """Import the course's file, unchanged, as module ``name`` (saved in ``tmp`` first)."""
    path = tmp / f"{name}.py"
    path.write_bytes(source(course))
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
