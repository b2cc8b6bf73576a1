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


def same_models(data_dir: Path, keys: dict[str, tuple[int, str]], models_dir: Path) -> None:
    """Refuses (one line) a data dir whose templates were made by other model files than `keys` (the models
    of `models_dir`, `index.features.embed.store_keys`), before the store is opened: opening it drops those
    templates for `posedesc serve` to make again, which `recognize` and `build-index` do not (a fuzzing of
    the CLI, 2026-12-08: a `recognize --models` of another folder emptied a data dir's depth templates, and
    the next recognition found nothing, exit 0)."""
    from index.store import changed_models

    if changed := changed_models(data_dir, keys):
        raise UserError(
            f"{data_dir}'s {', '.join(sorted(changed))} templates were made with other model files than those of "
            f"{models_dir}: pass the models they were made with (--models), or start `posedesc serve` on the "
            "data dir with these models once, which makes the templates again"
        )


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
    for name, what, kind in (
        ("fx", "focal x", bounded(1.0, 1e6)),
        ("fy", "focal y", bounded(1.0, 1e6)),
        ("cx", "principal point x", bounded(-1e6, 1e6)),
        ("cy", "principal point y", bounded(-1e6, 1e6)),
    ):
        p.add_argument(f"--{name}", type=kind, help=f"{what} of the frame, px{note}")


def bounded(low: float, high: float, *, above: bool = False):
    """An argparse type: a finite number from `low` (`above`: over it) to `high`, as the service's form takes
    it; anything else is refused with the range (a fuzzing of the CLI, 2026-12-08: --fx nan, --distance-mm inf
    and --fx -572 were answered, exit 0, with nothing found, invalid JSON or a wrong pose)."""

    def number(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (low < x if above else low <= x) or not x <= high:  # NaN fails both
            side = "over" if above else "from"
            raise argparse.ArgumentTypeError(f"{text}: a finite number {side} {low:g} to {high:g}")
        return x

    number.__name__ = "number"  # argparse names the type in its messages
    return number


def count(text: str) -> int:
    """An argparse type: a whole number of at least 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text}: at least 1")
    return n


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
    except OSError as e:
        # a path the user gave that cannot be written: a file where a folder goes, a name too long
        print(f"posedesc {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"posedesc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
