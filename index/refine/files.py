"""The objects' colour fit models kept on disk (`index.refine.colour.ColourModel`): made once per object,
then read back by every later cache miss and every later process instead of being made again.

Why: a colour model takes 0.2-0.5 s of CPU to make (600 silhouettes rasterised) and the service keeps 64 in
memory (`service.pipeline.fit.CAPACITY`); with more objects registered, or after a restart, a colour frame's
verification made them again on its own time (3 colour frames at the detect bench's 100 objects: 9 models
made, 2.5 of their 5.1 s; the worst frame 1.6-1.7 s against 0.6-0.8 s with the files: docs/experiments.md).
Read from its file, a model takes about a millisecond.

The files are a cache of what the mesh gives, never the truth: `<data_dir>/fit/colour-<version>/<object
id>-<registered>.npz`. The version is a digest of the code that makes a model, so a file made by other code
is never read; the registration's time (`ObjectRecord.created`, seconds) tells an object from another of the
same id in a store made anew in the same data dir. A file that cannot be read is made again; one that
cannot be written is only not kept. Replicas sharing a data dir share the files (each written whole, then
renamed: `write_atomic`); during an upgrade, a replica that starts sweeps the other version's files, which
are made again as needed."""

from __future__ import annotations

import contextlib
import hashlib
import io
import logging
import re
import shutil
import time
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from index import draw
from index.refine import colour
from index.refine.colour import ColourModel
from index.store.snapshot_files import write_atomic

log = logging.getLogger("index.refine")

FIT_DIR = "fit"
#: the files' layout; counted up when it changes
FORMAT = 1
#: a temporary file this old was left by a writer that died (a live one renames it within a second)
STALE_SECONDS = 600
_NAME = re.compile(r"^(\d+)-(\d+)\.npz$")


def version() -> str:
    """A digest of what a colour model's arrays depend on besides the mesh: its constants and the code that
    makes it (the colour fit's module and the drawing mesh's, which cuts the mesh it is made from). Any change
    there leaves the kept models unread: they are made again as needed, and the next start sweeps them."""
    h = hashlib.sha256(repr((FORMAT, colour.VIEWS, colour.POINTS, colour.MODEL_FACES)).encode())
    for module in (colour, draw):
        try:
            h.update(Path(module.__file__ or "-").read_bytes())
        except OSError:  # no source beside the code (a frozen build): the constants alone
            h.update(module.__name__.encode())
    return h.hexdigest()[:12]


class ColourFiles:
    """The colour models of a data dir's objects. `registered(object id)`: the object's registration time
    (None: not registered, whose model is neither read nor kept)."""

    def __init__(self, data_dir: Path, registered: Callable[[int], float | None]):
        self.root = Path(data_dir) / FIT_DIR
        self.dir = self.root / f"colour-{version()}"
        self.registered = registered

    def path(self, object_id: int) -> Path | None:
        created = self.registered(object_id)
        return None if created is None else self.dir / f"{int(object_id)}-{round(created)}.npz"

    def read(self, object_id: int) -> ColourModel | None:
        """The object's model from its file; None when there is none or it cannot be read."""
        path = self.path(object_id)
        if path is None:
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                return ColourModel(
                    z["directions"], z["coords"], z["angles"], float(z["unit"]), float(z["diameter"])
                )
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
            log.warning("%s cannot be read (%s): the colour model is made again", path, e)
            return None

    def write(self, object_id: int, model: ColourModel) -> None:
        """Keeps the object's model (not when it is no longer registered, or the disk refuses)."""
        path = self.path(object_id)
        if path is None:
            return
        buf = io.BytesIO()
        np.savez(buf, directions=model.directions, coords=model.coords, angles=model.angles,
                 unit=np.float64(model.unit), diameter=np.float64(model.diameter))  # fmt: skip
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            write_atomic(path, buf.getbuffer())
        except OSError as e:
            log.warning(
                "the colour model of object %d is not kept (%s): it is made again when needed", object_id, e
            )

    def remove(self, object_id: int) -> None:
        """Removes the files of an object (every registration of its id)."""
        for path in self.dir.glob(f"{int(object_id)}-*.npz"):
            _unlink(path)

    def sweep(self, objects: Mapping[int, float]) -> None:
        """Removes the files of other versions, of objects not in `objects` (id -> registration time) up to
        its highest id (a higher id may be another process's newer object), and temporary files left by a
        writer that died."""
        if not self.root.is_dir():
            return
        for other in self.root.glob("colour-*"):
            if other != self.dir:
                shutil.rmtree(other, ignore_errors=True)
        top = max(objects, default=0)
        for path in self.dir.glob("*.tmp") if self.dir.is_dir() else ():  # a writer killed before its rename
            with contextlib.suppress(OSError):
                if time.time() - path.stat().st_mtime > STALE_SECONDS:
                    _unlink(path)
        for path in self.dir.glob("*.npz") if self.dir.is_dir() else ():
            m = _NAME.match(path.name)
            if m is None or (int(m[1]) <= top and round(objects.get(int(m[1]), -1)) != int(m[2])):
                _unlink(path)


def _unlink(path: Path) -> None:
    """Removes a kept model; one the disk will not let go of is only logged (what it caches is gone)."""
    try:
        path.unlink(missing_ok=True)
    except OSError as e:
        log.warning("%s cannot be removed (%s)", path, e)
