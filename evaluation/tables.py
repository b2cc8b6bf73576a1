"""The README's tables from committed results: a table is columns and rows, each row one JSON file of
docs/results/ and the command that wrote it, each cell a key path in it with a format; `update` rewrites
each table between its `<!-- table:NAME -->` markers (`scripts/readme_tables.py` holds the README's own
tables; `tests/scripts/test_readme_tables.py` checks they are what their JSON says)."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: how a target shows a unit that is a format's name
UNITS = {"x": "×", "rps": "/s", "mb": "MB"}

# A column's `fmt` is a name here, optionally with a unit after a colon ("target:ms").
FORMATS: dict[str, Callable[[Any, str], str]] = {
    "pct": lambda x, _: f"{100 * float(x):.1f}",  # a share 0..1 as percent, one decimal
    "int": lambda x, _: f"{int(x):,}",
    "num": lambda x, _: f"{float(x):.2f}",
    "ms": lambda x, _: f"{float(x):.1f} ms",
    "s": lambda x, _: f"{float(x):.2f} s",
    # the bench's target as its JSON writes it ("<= 5"), with the unit
    "target": lambda x, unit: (
        f"{str(x).replace('<=', '≤').replace('>=', '≥')} {UNITS.get(unit, unit)}".strip()
    ),
    "met": lambda x, _: "met" if x else "**missed**",
    "x": lambda x, _: f"{float(x):.1f}×",  # a ratio
    "rps": lambda x, _: f"{float(x):.1f} /s",  # requests a second
    "mb": lambda x, _: f"{float(x):.2f} MB",
}


@dataclass(frozen=True)
class Column:
    header: str
    fmt: str = "text"
    #: default key path, dot-separated; `{name}` is filled from the row's `vars`; `FILE::path`: the figure
    #: of another file under docs/results/ (an earlier run's, beside the row's)
    path: str = ""


@dataclass(frozen=True)
class Row:
    label: str
    file: str  # under docs/results/
    command: str  # what wrote the file (shown as a footnote)
    vars: Mapping[str, str] = field(default_factory=dict)
    cells: Mapping[str, str] = field(default_factory=dict)  # column header -> key path, over the default


@dataclass(frozen=True)
class Table:
    name: str
    columns: tuple[Column, ...]
    rows: tuple[Row, ...]
    note: str = ""  # under the table, above the commands


class TableError(ValueError):
    """A row whose JSON file or key path is missing, or a README without the table's markers."""


def lookup(data: Any, path: str, file: str) -> Any:
    """`data` at the dot-separated `path` (keys of objects; numbers index lists)."""
    here = data
    for key in path.split("."):
        if isinstance(here, list) and key.isdigit() and int(key) < len(here):
            here = here[int(key)]
        elif isinstance(here, dict) and key in here:
            here = here[key]
        else:
            raise TableError(f"{file}: no {path!r} (stopped at {key!r})")
    return here


def render(table: Table, results: Path) -> str:
    """The table in Markdown, a row per spec, and the commands that made its files as footnotes."""
    cache: dict[str, Any] = {}
    commands: list[str] = []
    lines = [
        "| " + " | ".join(c.header for c in table.columns) + " | source |",
        "|" + "---|" * (len(table.columns) + 1),
    ]
    for row in table.rows:
        if row.file not in cache:
            path = results / row.file
            if not path.is_file():
                raise TableError(f"{row.label}: no result file {path}")
            cache[row.file] = json.loads(path.read_text())
        cells = [row.label]
        for col in table.columns[1:]:
            key = row.cells.get(col.header, col.path).format_map(row.vars)
            name, _, unit = col.fmt.format_map(row.vars).partition(":")
            file, _, key = (
                key.rpartition("::") if "::" in key else (row.file, "", key)
            )  # another file's figure
            if file not in cache:
                if not (results / file).is_file():
                    raise TableError(f"{row.label}: no result file {results / file}")
                cache[file] = json.loads((results / file).read_text())
            cells.append(FORMATS[name](lookup(cache[file], key, file), unit) if key else "")
        source = f"[`{row.file}`](docs/results/{row.file})"
        if row.command:
            if row.command not in commands:
                commands.append(row.command)
            source += f" ({commands.index(row.command) + 1})"
        lines.append("| " + " | ".join(cells + [source]) + " |")
    out = "\n".join(lines) + "\n"
    if table.note:
        out += f"\n{table.note}\n"
    if commands:
        out += "\n" + "".join(f"- ({i}) `{c}`\n" for i, c in enumerate(commands, 1))
    return out


def markers(name: str) -> re.Pattern[str]:
    return re.compile(rf"(<!-- table:{name} -->\n)(.*?)(<!-- /table:{name} -->)", re.S)


def update(text: str, tables: tuple[Table, ...], results: Path) -> str:
    """`text` (the README) with every table rewritten between its markers."""
    for table in tables:
        found = markers(table.name).findall(text)
        if len(found) != 1:
            raise TableError(f"README: want one <!-- table:{table.name} --> ... <!-- /table:{table.name} -->")
        body = render(table, results)

        def filled(m: re.Match[str], body: str = body) -> str:
            return m.group(1) + body + m.group(3)

        text = markers(table.name).sub(filled, text)
    return text
