"""Draw saved /recognize answers over their frame (a PNG).

`posedesc show FRAME ANSWER.json [ANSWER.json ...] --data-dir DIR` draws each answer as `POST /recognize`
returned it (its JSON, saved) over FRAME, as `POST /recognize/draw` does: the best answer's silhouette at
its pose, tinted and outlined, its axes (x red, y green, z blue) and its name and confidence; a rejected
best answer grey and dashed, "unknown?". Several answers (one per object asked about) go on one picture,
each in its own colour. The meshes are the registered ones, read (never written) from the service's data
dir: its `store.sqlite`, or `meshes/ID.glb` where a Milvus store keeps them.

A frame needs its intrinsics (`--fx --fy --cx --cy`, those sent with the query). Without them FRAME is the
patch that was sent: its answers are in the patch camera, at the distance of the first answer's `t`
(the distance the patch was cut at, when `distance_mm` was sent) and the model's window (`--window-mm`).
A 16-bit FRAME is a depth image, drawn in grey.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from posedesc.cli import UserError, camera_arguments

if TYPE_CHECKING:
    from index.draw import DrawMesh, Drawn


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "frame", type=Path, help="the image sent: a frame, or a patch (PNG or JPEG; 16-bit: depth)"
    )
    p.add_argument("answers", type=Path, nargs="+", help="/recognize answers as JSON files, one per query")
    p.add_argument("--data-dir", type=Path, required=True, help="the service's data dir (its meshes)")
    p.add_argument(
        "--out",
        type=Path,
        help="the PNG to write (default: FRAME's name + -answers.png in the current folder, never FRAME's)",
    )
    camera_arguments(p, " (a patch: none)")
    p.add_argument("--draw-k", type=int, default=1, help="answers of each JSON to draw, best first")
    p.add_argument("--window-mm", type=float, default=200.0, help="a patch's window (the shipped models')")


def run(args: argparse.Namespace) -> int:
    from index.draw import draw_answers, patch_view
    from index.features.patches import PatchSpec

    if args.draw_k < 1:
        raise UserError(f"--draw-k must be at least 1, got {args.draw_k}")
    image = read_image(args.frame)
    answers = [drawn for path in args.answers for drawn in read_answer(path, args.draw_k)]
    intrinsics = [args.fx, args.fy, args.cx, args.cy]
    if any(x is not None for x in intrinsics):
        if None in intrinsics:
            raise UserError("a frame needs all of --fx, --fy, --cx and --cy")
        K = np.array([[args.fx, 0.0, args.cx], [0.0, args.fy, args.cy], [0.0, 0.0, 1.0]])
    else:
        h, w = image.shape[:2]
        if abs(h - w) > 1:
            raise UserError(
                f"{args.frame} is {w} x {h} px, not a square patch: give its --fx, --fy, --cx, --cy"
            )
        distance = float(np.linalg.norm(answers[0][1].t)) if answers else 400.0
        image, K = patch_view(image, PatchSpec(size=w, window_mm=args.window_mm), distance)
    meshes = StoredMeshes(args.data_dir)
    drawn = [(meshes.get(oid, a.name), a) for oid, a in answers]
    # in the current folder: the input's may be a checkout or a dataset, which a picture must not dirty
    out = args.out or Path(f"{args.frame.stem}-answers.png")
    write_png(out, draw_answers(image, drawn, K))
    print(out)
    return 0


def read_image(path: Path) -> np.ndarray:
    """An image file as RGB (H, W, 3) uint8; a 16-bit one (depth, mm) in grey."""
    import cv2

    from index.draw import grey_to_rgb

    if not path.is_file():
        raise UserError(f"no such file: {path}")
    im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if im is None:
        raise UserError(f"{path} is not a readable image")
    if im.dtype == np.uint16 and im.ndim == 2:
        return grey_to_rgb(im.astype(np.float32))
    if im.dtype != np.uint8:
        raise UserError(
            f"{path}: an 8-bit image (colour) or a 16-bit single-channel one (depth), not {im.dtype}"
        )
    if im.ndim == 2:
        return np.repeat(im[..., None], 3, axis=2)
    return cv2.cvtColor(im[..., :3], cv2.COLOR_BGR2RGB)


def read_answer(path: Path, draw_k: int) -> list[tuple[int, Drawn]]:
    """The first `draw_k` matches of a saved /recognize answer, of each object found when it is a whole
    frame's: (object id, what to draw)."""
    from index.draw import Drawn

    if not path.is_file():
        raise UserError(f"no such file: {path}")
    try:
        answer = json.loads(path.read_text(encoding="utf-8"))
        # a whole frame's answer: every object found, each with its own matches (the top ones are the first's)
        found = answer.get("detections")
        runs = (
            [(d["matches"], False) for d in found]
            if found is not None
            else [(answer["matches"], answer["best"] is None)]
        )
        out = []
        for matches, rejected in runs:
            for m in matches[:draw_k]:
                R, t = np.array(m["R"], float).reshape(3, 3), np.array(m["t"], float).reshape(3)
                conf = None if m.get("confidence") is None else float(m["confidence"])
                out.append((int(m["object_id"]), Drawn(str(m["name"]), conf, R, t, rejected)))
    except (ValueError, KeyError, TypeError) as e:
        what = f"no {e}" if isinstance(e, KeyError) else str(e)
        raise UserError(f"{path} is not a /recognize answer as the API returns it ({what})") from None
    return out


class StoredMeshes:
    """The registered meshes of a data dir, read-only, as the drawing takes them (loaded once each)."""

    def __init__(self, data_dir: Path):
        if not data_dir.is_dir():
            raise UserError(f"no such data dir: {data_dir}")
        self.dir = data_dir
        self._cache: dict[int, DrawMesh] = {}

    def get(self, object_id: int, name: str) -> DrawMesh:
        from index.draw import DrawMesh

        if object_id not in self._cache:
            mesh = DrawMesh.from_glb(self._glb(object_id))
            if mesh is None:
                raise UserError(
                    f"object {object_id} ({name}) has no mesh in {self.dir}: deleted, or another data dir?"
                )
            self._cache[object_id] = mesh
        return self._cache[object_id]

    def _glb(self, object_id: int) -> bytes | None:
        db = self.dir / "store.sqlite"
        if db.is_file():
            # read-only: a running service may hold the store; this never takes its write lock
            con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
            try:
                row = con.execute("SELECT mesh FROM objects WHERE id = ?", (object_id,)).fetchone()
            except sqlite3.DatabaseError as e:
                raise UserError(f"{db} is not a readable store: {e}") from None
            finally:
                con.close()
            return None if row is None else row[0]
        glb = self.dir / "meshes" / f"{object_id}.glb"
        return glb.read_bytes() if glb.is_file() else None


def write_png(path: Path, image: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise UserError(f"could not write {path} (a .png name in a writable folder?)")
