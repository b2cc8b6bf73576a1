"""`posedesc --help` and each subcommand's help, as a user sees them in an 80-column terminal."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from posedesc.cli import COMMANDS, HelpFormatter, _module, summary


def helptext(*args: str) -> str:
    exe = Path(sys.executable).parent / "posedesc"
    env = {**os.environ, "COLUMNS": "80"}
    r = subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_one_line_per_subcommand():
    lines = helptext("--help").splitlines()
    for name in COMMANDS:
        line = summary(name)
        assert line and len(line) <= 60, (name, line)  # fits one line after the name column in 80 columns
        mine = [x for x in lines if x.split()[:1] == [name]]
        assert len(mine) == 1 and mine[0].split(None, 1)[1] == line, (name, mine)
    assert "see `posedesc" not in "\n".join(lines)


def _shown_defaults(name: str) -> dict[str, str]:
    """Each option that has a default worth showing, and how its help shows it."""
    p = argparse.ArgumentParser(formatter_class=HelpFormatter)
    _module(name).add_arguments(p)
    out = {}
    for a in p._actions:
        d = a.default
        if not a.option_strings or a.required or d is None or isinstance(d, bool) or d in ("", ()):
            continue
        if argparse.SUPPRESS in (d, a.help):  # --help
            continue
        if isinstance(d, tuple):
            out[a.option_strings[0]] = ",".join(":".join(f"{x:g}" for x in b) for b in d)
        else:
            out[a.option_strings[0]] = str(d)
    return out


@pytest.mark.parametrize("name", COMMANDS)
def test_every_default_is_in_the_subcommand_help(name):
    text = " ".join(helptext(name, "--help").split())  # wrapping undone
    defaults = _shown_defaults(name)
    assert defaults, name
    for option, shown in defaults.items():
        after = text.split(f" {option} ", 1)[-1].split(" --", 1)[0]  # this option's help
        assert f"(default: {shown})" in after, (option, after)
