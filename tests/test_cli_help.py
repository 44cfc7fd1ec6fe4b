"""The `icefloe` command explains itself: help on every verb and option, shell completion."""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import pytest
from conftest import ROOT

from icefloe.cli import parser


def verbs() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_every_verb_and_option_has_help() -> None:
    listed = {a.dest for a in next(a for a in parser()._actions
                                   if isinstance(a, argparse._SubParsersAction))._choices_actions}
    missing = []
    for name, p in verbs().items():
        if name not in listed:
            missing.append(f"{name}: not in `icefloe --help`")
        if not p.description:
            missing.append(f"{name}: no description")
        if not p.prog.startswith("icefloe "):
            missing.append(f"{name}: usage says {p.prog!r}")
        for action in p._actions:
            if not isinstance(action, argparse._HelpAction) and not action.help:
                missing.append(f"{name} {'/'.join(action.option_strings) or action.dest}: no help")
    assert not missing, "\n".join(missing)
    assert {"topics", "info", "services", "teleop", "viz", "completion"} <= set(verbs())


@pytest.mark.parametrize("verb", sorted(verbs()))
def test_help_of_every_verb_prints(verb: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        parser().parse_args([verb, "--help"])
    assert done.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: icefloe {verb}")


def test_help_from_the_installed_command_anywhere() -> None:
    res = subprocess.run([str(ROOT / ".venv/bin/icefloe"), "viz", "--help"], capture_output=True, text=True,
                         timeout=60, cwd="/")
    assert res.returncode == 0 and res.stdout.startswith("usage: icefloe viz"), res.stdout + res.stderr


def complete(line: str, tmp_path: Path) -> list[str]:
    """What bash offers for Tab at the end of ``line``, with icefloe's completion loaded."""
    words = line.split(" ")
    script = (f'eval "$({ROOT}/.venv/bin/icefloe completion bash)"\n'
              f"COMP_LINE={line!r}; COMP_POINT=${{#COMP_LINE}}; COMP_WORDS=({' '.join(repr(w) for w in words)})\n"
              f"COMP_CWORD={len(words) - 1}\n"
              f"_python_argcomplete {words[0]!r} {words[-1]!r} {words[-2]!r}\n"
              'printf "%s\\n" "${COMPREPLY[@]}"\n')
    res = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    return [w.strip() for w in res.stdout.splitlines() if w.strip()]


def test_bash_completes_verbs_keys_and_configs(tmp_path: Path) -> None:
    icefloe = f"{ROOT}/.venv/bin/icefloe"
    assert {"teleop", "topics"} <= set(complete(f"{icefloe} t", tmp_path))
    assert complete(f"{icefloe} echo odom/p", tmp_path) == ["odom/pose"]
    assert "sim" in complete(f"{icefloe} status --config s", tmp_path)
