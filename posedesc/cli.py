"""`posedesc`: one console script, one module per subcommand under posedesc/commands/.

Subcommand modules are imported only when used, so `posedesc serve` never imports torch; `posedesc --help`
reads their docstrings without importing them. Each module has `add_arguments(parser)`, `run(args) -> int`
and a `__doc__` whose first line (at most 60 characters: one line of `posedesc --help` in 80 columns) says
what it does. Errors a user can fix (`UserError`, `ValueError` from input checks) print one line, exit 2."""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import logging
import sys
from pathlib import Path

COMMANDS = ("render", "train", "export", "build-index", "serve", "recognize", "show", "evaluate", "bench")


class UserError(ValueError):
    """Bad input from the user: printed as one line, no traceback."""


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Each option's help ends with its default, except where there is none to show (None, a flag)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text, default = action.help or "", action.default
        if action.required or default is None or isinstance(default, bool) or default in ("", ()):
            return text
        if "%(default)" in text or default is argparse.SUPPRESS:
            return text
        if isinstance(default, tuple):  # blocks of fractions, as typed: A:B,C:D
            shown = ",".join(":".join(f"{x:g}" for x in block) for block in default)
            return f"{text} (default: {shown})"
        return text + " (default: %(default)s)"


def camera_arguments(p: argparse.ArgumentParser, note: str = "") -> None:
    """`--fx --fy --cx --cy`: a frame's intrinsics in px, as the subcommands that take a frame name them."""
    for name, what in (
        ("fx", "focal x"),
        ("fy", "focal y"),
        ("cx", "principal point x"),
        ("cy", "principal point y"),
    ):
        p.add_argument(f"--{name}", type=float, help=f"{what} of the frame, px{note}")


def _module_name(name: str) -> str:
    return f"posedesc.commands.{name.replace('-', '_')}"


def _module(name: str):
    return importlib.import_module(_module_name(name))


def summary(name: str) -> str | None:
    """The first line of a subcommand's docstring, read from its source (None: not in this build)."""
    spec = importlib.util.find_spec(_module_name(name))
    if spec is None or spec.origin is None:
        return None
    doc = ast.get_docstring(ast.parse(Path(spec.origin).read_text(encoding="utf-8")))
    return doc.splitlines()[0] if doc else ""


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog="posedesc", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    wanted = next((a for a in argv if a in COMMANDS), None)
    for name in COMMANDS:
        try:
            mod = _module(name) if name == wanted else None
        except ModuleNotFoundError as e:
            if e.name and e.name.startswith("posedesc.commands"):
                mod = None
            else:
                raise
        line = summary(name)
        p = sub.add_parser(
            name,
            help=line if line is not None else "not available in this build",
            description=mod.__doc__ if mod else line,
            formatter_class=HelpFormatter,
        )
        if mod is not None:
            mod.add_arguments(p)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s"
    )
    try:
        mod = _module(args.command)
    except ModuleNotFoundError:
        print(f"posedesc: error: {args.command} is not available in this build", file=sys.stderr)
        return 2
    try:
        return int(mod.run(args) or 0)
    except (UserError, ValueError, FileNotFoundError) as e:
        print(f"posedesc {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"posedesc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
