"""Files the Milvus store's replicas share in their common data directory: meshes, local features, meta
flags, job states. Each file is written whole through a temporary file and a rename, so a reader on any
replica sees the old content or the new, never a part (true of local file systems and NFS)."""

from __future__ import annotations

import io
import os
import time
from pathlib import Path

import numpy as np

from index.store.snapshot_files import write_atomic


class SharedFiles:
    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, name: str) -> Path:
        p = (self.root / name).resolve()
        if self.root.resolve() not in p.parents:
            raise ValueError(f"{name!r} is outside the shared directory")
        return p

    def write(self, name: str, content: bytes) -> None:
        p = self.path(name)
        p.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(p, content)

    def read(self, name: str) -> bytes | None:
        try:
            return self.path(name).read_bytes()
        except FileNotFoundError:
            return None

    def remove(self, name: str) -> None:
        self.path(name).unlink(missing_ok=True)

    def claim(self, name: str, stale_seconds: float) -> bool:
        """Creates `name` if it does not exist (O_EXCL: one replica wins, on local file systems and NFS v3+);
        a claim older than `stale_seconds` (its replica died) is taken over. True for the winner."""
        p = self.path(name)
        p.parent.mkdir(parents=True, exist_ok=True)
        try:
            if time.time() - p.stat().st_mtime > stale_seconds:
                p.unlink(missing_ok=True)
        except FileNotFoundError:
            pass
        try:
            os.close(os.open(p, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return False
        return True

    def names(self, folder: str) -> list[str]:
        d = self.path(folder)
        return sorted(p.name for p in d.iterdir() if not p.name.startswith(".")) if d.is_dir() else []

    def write_arrays(self, name: str, **arrays: np.ndarray) -> None:
        buf = io.BytesIO()
        np.savez(buf, **arrays)  # type: ignore[arg-type]
        self.write(name, buf.getvalue())

    def read_arrays(self, name: str) -> dict[str, np.ndarray] | None:
        data = self.read(name)
        if data is None:
            return None
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
