"""`posedesc`: one console script, one module per subcommand under posedesc/commands/.

Subcommand modules are imported only when used, so `posedesc serve` never imports torch.
Each module has `add_arguments(parser)` and `run(args) -> int`, and a one-line `__doc__`.
Errors a user can fix (`UserError`, `ValueError` from input checks) print one line, exit 2."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

COMMANDS = ("render", "train", "export", "build-index", "serve", "evaluate", "bench")


class UserError(ValueError):
    """Bad input from the user: printed as one line, no traceback."""


def _module(name: str):
    return importlib.import_module(f"posedesc.commands.{name.replace('-', '_')}")


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
        help_text = (mod.__doc__ or "").strip().splitlines()[0] if mod and mod.__doc__ else None
        p = sub.add_parser(name, help=help_text or f"see `posedesc {name} --help`", description=help_text)
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
