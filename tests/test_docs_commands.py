"""Every command in the README and docs/ runs as written.

Each line of a ```bash block (and each ``$ `` line of a ```console block) in a Markdown file of
the repository is one test: run from the repository root with bash, in a pseudo-terminal, as a
student would type it in a new terminal (the venv not activated, no display). The student's home
is a temporary folder whose ``~/.config/icefloe/robots/sim.toml`` puts the simulated robot ``sim``
on a free port, so the commands mean what they say without colliding with other tests.

An HTML comment just before a block says how its commands run (the convention, for whoever
writes docs, is in docs/DEVELOPING.md, "Commands in the docs")::

    <!-- doc-test: robot -->            the simulated robot is running (./deploy/up.sh in another terminal)
    <!-- doc-test: until-ctrl-c -->     each command may run until Ctrl-C (a stack, a listener):
                                        once it has printed something and run a while more, it
                                        must still run (or have exited 0); Ctrl-C then ends it
                                        cleanly. So such a program says something when it is up.
    <!-- doc-test: settle 20 -->        with until-ctrl-c: that while is 20 s (default 3)
    <!-- doc-test: skip REASON -->      not run here; REASON shows in the test report
    <!-- doc-test: cwd ~/certs -->      run in this folder (made first), not the repository's root
    <!-- doc-test: file ~/hello.py -->  (before any block) the block is saved there first

The commands of one page share one home, in order, as in one student's session: a file one
command makes is there for the next.

Directives combine with commas: ``<!-- doc-test: robot, until-ctrl-c -->``. Commands outside
such blocks (an indented block, a fence without a language) fail `test_commands_are_in_bash_blocks`,
so none is left unchecked; inline ones (`` `icefloe echo log` ``) are checked to name a real verb
and options, or an existing file.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import ROOT, free_port
from terminal import Terminal

DOCS = sorted(p.relative_to(ROOT) for p in [*ROOT.glob("*.md"), *ROOT.glob("docs/*.md"),
                                             *ROOT.glob("examples/*.md"), *ROOT.glob("schemas/*.md")])
COMMAND_BLOCKS = {"bash", "sh", "shell", "console"}
DIRECTIVE = re.compile(r"<!--\s*doc-test:\s*(.*?)\s*-->")
LOOKS_LIKE_A_COMMAND = re.compile(r"^\s*(\$ |\.venv/bin/|\./(deploy|tests)/|python3? -m |icefloe [a-z])")
FINITE_TIMEOUT_S = 120.0
STARTUP_TIMEOUT_S = 60.0
SIMULATED = ("sim", "sim-icoboard", "sim-calibration")
"""The shipped robot configs a documented command may run: each gets a port of the test's own."""


@dataclass
class Block:
    doc: Path
    line: int
    lang: str
    text: str
    directives: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Command:
    doc: Path
    line: int
    text: str
    directives: tuple[tuple[str, str], ...]

    def has(self, name: str) -> bool:
        return any(k == name for k, _ in self.directives)

    def get(self, name: str, default: str = "") -> str:
        return next((v for k, v in self.directives if k == name), default)

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}: {self.text[:60]}"


def parse_directives(text: str) -> dict[str, str]:
    """``robot, until-ctrl-c, settle 9`` -> {robot: "", until-ctrl-c: "", settle: "9"}; ``skip`` takes
    the rest of the comment as its reason (commas and all)."""
    text, _, reason = text.partition("skip")
    out = {"skip": reason.strip()} if _ else {}
    for part in text.split(","):
        name, _, value = part.strip().partition(" ")
        if name:
            out[name] = value.strip()
    return out


def blocks(doc: Path) -> Iterator[Block]:
    """The fenced code blocks of a Markdown file, with the directives of the comment before each."""
    lines = (ROOT / doc).read_text().splitlines()
    i, pending = 0, {}
    while i < len(lines):
        stripped = lines[i].strip()
        if m := DIRECTIVE.fullmatch(stripped):
            pending = {**pending, **parse_directives(m.group(1))}
        elif stripped.startswith(("```", "~~~")):
            fence, lang = stripped[:3], stripped[3:].strip().split(" ")[0].lower()
            start, body = i + 1, []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith(fence):
                body.append(lines[i])
                i += 1
            indent = min((len(b) - len(b.lstrip()) for b in body if b.strip()), default=0)
            yield Block(doc, start, lang, "\n".join(b[indent:] for b in body), pending)
            pending = {}
        elif stripped:
            pending = {}
        i += 1


def commands(block: Block) -> Iterator[tuple[int, str]]:
    """(line, command) of a bash or console block: comments dropped, ``\\`` continuations joined."""
    lines = block.text.splitlines()
    i = 0
    while i < len(lines):
        line, number = lines[i], block.line + i + 1
        if block.lang == "console":
            if not line.startswith("$ "):
                i += 1
                continue
            line = line[2:]
        while line.rstrip().endswith("\\") and i + 1 < len(lines):
            i += 1
            line = line.rstrip()[:-1].rstrip() + " " + lines[i].strip()
        i += 1
        code = strip_comment(line).strip()
        if code:
            yield number, code


def strip_comment(line: str) -> str:
    """The line without a trailing ``# comment`` (a ``#`` inside quotes stays)."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i]
    return line


def all_commands() -> list[Command]:
    out = []
    for doc in DOCS:
        for block in blocks(doc):
            if block.lang in COMMAND_BLOCKS:
                for line, text in commands(block):
                    out.append(Command(doc, line, text, tuple(block.directives.items())))
    return out


def files_of(doc: Path) -> list[Block]:
    return [b for b in blocks(doc) if "file" in b.directives]


# ---------------------------------------------------------------------- where the commands run


@dataclass
class Home:
    """A student's home folder whose robot ``sim`` is the simulated one on a port of its own."""

    path: Path
    port: int

    @classmethod
    def make(cls, folder: Path) -> Home:
        port = free_port()
        robots = folder / ".config" / "icefloe" / "robots"
        robots.mkdir(parents=True)
        for name in SIMULATED:  # your own sim.toml, over the shipped one (see icefloe/paths.py)
            (robots / f"{name}.toml").write_text(
                f'extends = "{name}"\nrun_dir = "{folder}/run-{name}"\n[webapi]\nport = {free_port()}\n'
                f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\nconnect = ["tcp/127.0.0.1:{port}"]\n')
        return cls(folder, port)

    def env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items()
               if k not in ("DISPLAY", "WAYLAND_DISPLAY", "VIRTUAL_ENV", "ICEFLOE_CONFIG_DIR", "XDG_CONFIG_HOME")
               and not k.startswith("PYTEST")}
        return {**env, "HOME": str(self.path), "PATH": "/usr/local/bin:/usr/bin:/bin", "TERM": "xterm"}

    def write_files(self, doc: Path) -> None:
        for block in files_of(doc):
            target = Path(block.directives["file"].replace("~", str(self.path), 1))
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.text + "\n")


def icefloe(home: Home, *args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(ROOT / ".venv/bin/icefloe"), *args], env=home.env(), cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def docs_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Home]:
    """The simulated robot, every service, as `./deploy/up.sh` runs it in another terminal."""
    home = Home.make(tmp_path_factory.mktemp("robot-home"))
    log = open(home.path / "up.log", "wb")  # noqa: SIM115
    up = subprocess.Popen([str(ROOT / ".venv/bin/icefloe"), "up", "--no-viz"], env=home.env(), cwd=ROOT,
                          stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        while not {"hwbridge", "odometry", "info", "sim"} <= set(icefloe(home, "status").stdout.split()):
            assert up.poll() is None and time.monotonic() < deadline, (home.path / "up.log").read_text()
            time.sleep(1.0)
        yield home
    finally:
        up.send_signal(2)
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(up.pid, 9)
        log.close()


@pytest.fixture(scope="module")
def homes(tmp_path_factory: pytest.TempPathFactory) -> dict[Path, Home]:
    """One home per page, kept while the page's commands run in order."""
    return {}


def run_in_terminal(command: Command, home: Home) -> None:
    home.write_files(command.doc)
    cwd = ROOT
    if command.has("cwd"):
        cwd = Path(command.get("cwd").replace("~", str(home.path), 1))
        cwd.mkdir(parents=True, exist_ok=True)
    term = Terminal(["bash", "-c", command.text], cwd=cwd, env=home.env())
    try:
        if command.has("until-ctrl-c"):
            settle = float(command.get("settle", "3"))
            deadline = time.monotonic() + STARTUP_TIMEOUT_S
            while term.alive() and not term.text.strip() and time.monotonic() < deadline:
                time.sleep(0.1)  # a Ctrl-C before it is up would only test Python's imports
            deadline = time.monotonic() + settle
            while term.alive() and time.monotonic() < deadline:
                time.sleep(0.2)
            if term.alive():
                term.ctrl_c()
                code = term.wait(60)
                assert code in (0, 130, -2), f"exit {code} after Ctrl-C:\n{term.text[-4000:]}"
            else:
                code = term.wait(5)
                assert code == 0, f"ended by itself with {code} within {settle} s:\n{term.text[-4000:]}"
        else:
            code = term.wait(float(command.get("timeout", FINITE_TIMEOUT_S)))
            assert code == 0, f"exit {code}:\n{term.text[-4000:]}"
        assert "Traceback" not in term.text, term.text[-4000:]
    finally:
        term.kill()


COMMANDS = all_commands()


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS, ids=[c.id for c in COMMANDS])
def test_documented_command_runs(command: Command, request: pytest.FixtureRequest, homes: dict[Path, Home],
                                 tmp_path_factory: pytest.TempPathFactory) -> None:
    if command.has("skip"):
        pytest.skip(f"{command.doc}:{command.line}: not run here: {command.get('skip') or 'no reason given'}")
    if command.has("robot"):
        home = request.getfixturevalue("docs_robot")
    elif command.doc not in homes:
        home = homes[command.doc] = Home.make(tmp_path_factory.mktemp("home"))
    else:
        home = homes[command.doc]
    run_in_terminal(command, home)


# ---------------------------------------------------------------------- nothing left unchecked


def test_commands_are_in_bash_blocks() -> None:
    """A command in an indented block or a fence without a language would never run: move it."""
    stray = []
    for doc in DOCS:
        text = (ROOT / doc).read_text().splitlines()
        fenced = set()
        for block in blocks(doc):
            body = range(block.line, block.line + len(block.text.splitlines()))
            fenced.update(body)
            if block.lang not in COMMAND_BLOCKS and block.lang in ("", "text", "sh-session"):
                stray += [f"{doc}:{n + 1}: {text[n].strip()}" for n in body if LOOKS_LIKE_A_COMMAND.match(text[n])]
        previous_blank = True
        for n, line in enumerate(text):
            if n not in fenced and line.startswith("    ") and previous_blank and LOOKS_LIKE_A_COMMAND.match(line):
                stray.append(f"{doc}:{n + 1}: {line.strip()}")
            previous_blank = not line.strip() or (previous_blank and line.startswith("    "))
    assert not stray, ("commands outside ```bash blocks (put them in one, or in ```console with `$ `, "
                       "and mark with <!-- doc-test: ... --> what they need):\n" + "\n".join(stray))


INLINE = re.compile(r"`((?:\.venv/bin/)?icefloe [^`]+|\./[\w./-]+\.sh[^`]*|\.venv/bin/python [^`]+)`")


def inline_commands() -> list[tuple[str, str]]:
    found = []
    for doc in DOCS:
        for n, line in enumerate((ROOT / doc).read_text().splitlines(), 1):
            found += [(f"{doc}:{n}", m.group(1)) for m in INLINE.finditer(line)]
    return found


def test_inline_commands_name_real_verbs_and_files() -> None:
    """`icefloe VERB ...` in running text parses with icefloe's own parser; a script path exists."""
    from icefloe.cli import parser

    bad = []
    for where, text in inline_commands():
        words = [w for w in shlex.split(text.replace("...", "")) if w != "\\"]
        if words[0].endswith("icefloe"):
            try:
                parser().parse_args(words[1:])
            except SystemExit:
                bad.append(f"{where}: `{text}` is not a valid icefloe command")
        else:
            script = words[1] if words[0].endswith("python") else words[0]
            if not script.startswith("-") and not (ROOT / script).exists() and "<" not in script:
                bad.append(f"{where}: `{text}`: no file {script}")
    assert not bad, "\n".join(bad)


def test_the_parser_finds_commands_and_directives(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    doc = tmp_path / "x.md"
    doc.write_text("text\n\n<!-- doc-test: robot, until-ctrl-c, settle 9 -->\n```bash\n"
                   ".venv/bin/icefloe echo log   # a comment\nicefloe pub cmd/twist '{\"v\": 1}' \\\n"
                   "    --rate 10\n```\n\n```console\n$ ./deploy/up.sh --dry-run\noutput # not a command\n```\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    found = [(line, text, dict(d)) for b in blocks(Path("x.md")) for line, text in commands(b)
             for d in [b.directives]]
    assert found == [
        (5, ".venv/bin/icefloe echo log", {"robot": "", "until-ctrl-c": "", "settle": "9"}),
        (6, "icefloe pub cmd/twist '{\"v\": 1}' --rate 10", {"robot": "", "until-ctrl-c": "", "settle": "9"}),
        (11, "./deploy/up.sh --dry-run", {}),
    ]
