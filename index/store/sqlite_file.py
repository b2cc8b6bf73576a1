"""The embedded store's SQLite file: its schema, the check that a file found is a usable store (`check_store`), and
whether an error is a full disk."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from index.store.records import StoreError

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS models (name TEXT PRIMARY KEY, fingerprint TEXT NOT NULL, dim INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS objects (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    symmetry TEXT NOT NULL,
    faces INTEGER NOT NULL,
    created REAL NOT NULL,
    extra TEXT NOT NULL,
    mesh BLOB
);
CREATE TABLE IF NOT EXISTS templates (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    object_id INTEGER NOT NULL REFERENCES objects(id) ON DELETE CASCADE,
    model TEXT NOT NULL,
    azimuth REAL NOT NULL,
    elevation REAL NOT NULL,
    inplane REAL NOT NULL,
    descriptor BLOB NOT NULL,
    local BLOB
);
CREATE INDEX IF NOT EXISTS templates_model ON templates(model, object_id);
INSERT OR IGNORE INTO meta VALUES ('generation', '0');
"""


def check_store(data_dir: str | Path) -> None:
    """Raises StoreError (one line) when `data_dir/store.sqlite` exists and SQLite finds it damaged;
    `posedesc serve` calls it before starting, so a damaged store stops it with a message, not a traceback."""
    path = Path(data_dir) / "store.sqlite"
    if not path.is_file():
        return
    try:
        db = sqlite3.connect(path)
    except sqlite3.Error as e:
        raise StoreError(f"{path} is not a usable store: {e}") from None
    try:
        check_sqlite(db, path)
    finally:
        db.close()


def changed_models(data_dir: str | Path, models: dict[str, tuple[int, str]]) -> dict[str, str]:
    """The models of `models` (name -> (dim, fingerprint), as a store is opened with) whose templates in
    `data_dir/store.sqlite` were made by another model file: name -> that file's fingerprint. Read only: opening
    the store drops such a model's templates for the service to make again at its start, which a command
    that does not make them (`posedesc recognize`, `build-index`) must not do. Nothing for a store not there
    or that does not read (opening it then says why)."""
    path = Path(data_dir) / "store.sqlite"
    if not path.is_file():
        return {}
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            known = recorded_models(db)
        finally:
            db.close()
    except sqlite3.Error:
        return {}
    return {n: known[n][1] for n, key in models.items() if n in known and known[n] != tuple(key)}


def recorded_models(db: sqlite3.Connection) -> dict[str, tuple[int, str]]:
    """The models a store's templates were made with, as a store is opened with them: name -> (dim,
    fingerprint)."""
    return {n: (int(d), str(f)) for n, f, d in db.execute("SELECT name, fingerprint, dim FROM models")}


def check_sqlite(db: sqlite3.Connection, path: Path) -> None:
    try:
        problems = [row[0] for row in db.execute("PRAGMA quick_check(3)")]
    except sqlite3.DatabaseError as e:
        raise StoreError(f"{path} is not a usable store: {e}") from None
    if problems != ["ok"]:
        # a problem may span lines ("*** in database main ***\nPage 8: ..."): the first real one
        lines = [ln for p in problems for ln in p.splitlines() if ln.strip() and not ln.startswith("***")]
        raise StoreError(
            f"{path} is damaged ({(lines or problems)[0]}); restore it from a backup, or move it away "
            "to start empty"
        )


def disk_full(e: BaseException) -> bool:
    return isinstance(e, sqlite3.Error) and getattr(e, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL
