"""Recognise the registered objects in image files, no server.

`posedesc recognize FRAME [FRAME ...] --data-dir DIR --fx .. --fy .. --cx .. --cy ..` answers each frame as
the service does with the objects registered in the service's data dir (its models from `--models`), in
this process, no server needed: every registered object found in the frame, or with `--u --v` the object
there (`--distance-mm` for colour alone). Each answer is written as the API's JSON (`NAME.json`) and
drawn (`NAME-answers.png`, as /recognize/draw) into `--out`.

Depth: `--depth FILE` beside one frame; for a folder in BOP's layout (`rgb/`, `depth/`, `scene_camera.json`)
each colour frame takes the depth of the same name. The camera: `--fx --fy --cx --cy`, or `--camera
scene_camera.json` (BOP: each frame's `cam_K` and `depth_scale`, by the frame's number). A folder is
answered frame by frame with a progress bar; a frame that cannot be answered is named with the reason and
the others go on (exit status 1 when any failed).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from posedesc.cli import UserError, bounded, camera_arguments, count, same_models

IMAGES = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True)
class Frame:
    """One image to answer, its depth (or None) and its camera (fx, fy, cx, cy) and depth scale."""

    rgb: Path | None
    depth: Path | None
    camera: tuple[float, float, float, float] | None
    depth_scale: float | None  # None: the depth file's own unit (mm for 16-bit, metres for float)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "frames",
        type=Path,
        nargs="+",
        help="colour images (PNG or JPEG; a 16-bit PNG is depth), or folders of them (BOP: rgb/ and depth/)",
    )
    p.add_argument("--data-dir", type=Path, required=True, help="the service's data dir (registered objects)")
    p.add_argument("--models", type=Path, default=Path("models"), help="models folder")
    p.add_argument("--out", type=Path, default=Path("out/recognize"), help="folder for the answers")
    p.add_argument(
        "--depth", type=Path, help="the depth of the one frame given (16-bit PNG, or float .npy/TIFF)"
    )
    p.add_argument(
        "--depth-scale",
        type=bounded(0.0, 1000.0, above=True),
        help="mm per depth unit (default: the file's: mm, or metres if float)",
    )
    camera_arguments(p)
    p.add_argument("--camera", type=Path, help="BOP scene_camera.json: each frame's cam_K and depth_scale")
    p.add_argument(
        "--u", type=bounded(-1e6, 1e6), help="the object's centre x, px (with --v: that object only)"
    )
    p.add_argument("--v", type=bounded(-1e6, 1e6), help="the object's centre y, px")
    p.add_argument(
        "--distance-mm",
        type=bounded(0.0, 1e5, above=True),  # the service's MAX_DISTANCE_MM
        help="the object's distance (colour alone, with --u --v)",
    )
    p.add_argument("--k", type=count, default=5, help="answers per object (default 5)")
    p.add_argument("--max-detections", type=count, default=10, help="objects a frame reports at most")
    p.add_argument(
        "--min-confidence", type=bounded(0.0, 1.0), help="report objects found with at least this confidence"
    )
    p.add_argument("--no-draw", action="store_true", help="write the JSON answers only")


def run(args: argparse.Namespace) -> int:
    frames = list_frames(args)
    state = _state(args)
    from tqdm import tqdm

    from service.answers import answer, answer_and_drawing
    from service.errors import ApiError
    from service.pipeline.query import Query
    from service.state import close_state

    args.out.mkdir(parents=True, exist_ok=True)
    failed, warned = 0, set[str]()
    try:
        for f in tqdm(frames, desc="frames", unit="frame", disable=len(frames) == 1 or None):
            name = (f.rgb or f.depth).stem  # type: ignore[union-attr]
            if len(frames) == 1:  # no bar for one frame: a line, so that the wait is never silent
                say(f"answering {f.rgb or f.depth} ...")
            fx, fy, cx, cy = f.camera if f.camera else (None, None, None, None)
            q = Query(
                f.rgb.read_bytes() if f.rgb else None,
                f.depth.read_bytes() if f.depth else None,
                f.depth_scale,
                fx,
                fy,
                cx,
                cy,
                args.u,
                args.v,
                args.distance_mm,
                args.k,
                args.max_detections,
                args.min_confidence,
            )
            try:
                if args.no_draw:
                    body = answer(state, q)
                else:  # decoded and run once for both
                    body, png = answer_and_drawing(state, q, 1 if q.finds else min(args.k, 3))
                    (args.out / f"{name}-answers.png").write_bytes(png)
                (args.out / f"{name}.json").write_text(json.dumps(body.model_dump(), indent=1) + "\n")
                for w in set(body.warnings) - warned:  # each once, not once a frame
                    tqdm.write(f"warning: {w}", file=sys.stderr)
                    warned.add(w)
            except ApiError as e:
                failed += 1
                if len(frames) == 1:
                    raise UserError(f"{f.rgb or f.depth}: {e.detail}") from None
                tqdm.write(f"{f.rgb or f.depth}: {e.detail}", file=sys.stderr)
    finally:
        close_state(state)
    print(f"{len(frames) - failed} of {len(frames)} frames answered into {args.out}")
    return 1 if failed else 0


def list_frames(args: argparse.Namespace) -> list[Frame]:
    """The frames asked for, each with its depth and camera; refuses (one line) what cannot be answered."""
    pairs: list[tuple[Path | None, Path | None]] = []
    for path in args.frames:
        if path.is_dir():
            pairs += _folder(path)
        elif path.is_file():
            pairs.append((path, args.depth))
        else:
            raise UserError(f"no such file or folder: {path}")
    if not pairs:
        raise UserError(f"no PNG or JPEG images in {', '.join(map(str, args.frames))}")
    if args.depth is not None and (len(pairs) != 1 or not args.depth.is_file()):
        raise UserError("--depth goes with one frame (a folder takes its depth from depth/)")
    given = [args.fx, args.fy, args.cx, args.cy]
    if any(x is not None for x in given) and None in given:
        raise UserError("a camera needs all of --fx, --fy, --cx and --cy")
    if args.camera is not None and any(x is not None for x in given):
        raise UserError("give the camera either as --fx --fy --cx --cy or as --camera, not both")
    cameras = _bop_cameras(args.camera) if args.camera is not None else None
    frames = []
    for rgb, depth in pairs:
        rgb, depth = _depth_alone(rgb, depth)
        camera = (args.fx, args.fy, args.cx, args.cy) if args.fx is not None else None
        scale: float | None = None
        if cameras is not None:
            key = _frame_number((rgb or depth).stem)  # type: ignore[union-attr]
            if key not in cameras:
                raise UserError(f"{args.camera} has no camera for frame {key} ({rgb or depth})")
            camera, scale = cameras[key]
        if args.depth_scale is not None:
            scale = args.depth_scale
        if args.u is None and camera is None:
            raise UserError(
                "to find the objects in a frame give its camera (--fx --fy --cx --cy, or --camera)"
            )
        frames.append(Frame(rgb, depth, camera, scale))
    return frames


def _folder(folder: Path) -> list[tuple[Path | None, Path | None]]:
    """A BOP scene folder (rgb/, depth/ of the same names) or a folder of images."""
    if (folder / "rgb").is_dir():
        depth = folder / "depth"
        return [
            (p, depth / f"{p.stem}.png" if (depth / f"{p.stem}.png").is_file() else None)
            for p in sorted((folder / "rgb").iterdir())
            if p.suffix.lower() in IMAGES
        ]
    return [(p, None) for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGES]


def _depth_alone(rgb: Path | None, depth: Path | None) -> tuple[Path | None, Path | None]:
    """A 16-bit PNG given as the frame is the depth image, sent alone."""
    if rgb is not None and depth is None and rgb.suffix.lower() == ".png":
        from PIL import Image

        try:
            with Image.open(rgb) as im:
                if im.mode in ("I", "I;16", "I;16B", "I;16L"):
                    return None, rgb
        except (OSError, ValueError):  # no image: refused when it is answered, the other frames go on
            return rgb, depth
    return rgb, depth


def _frame_number(stem: str) -> str:
    try:
        return str(int(stem))
    except ValueError:
        raise UserError(
            f"{stem}: BOP frames are named by their number (000003.png) to find their camera"
        ) from None


def _bop_cameras(path: Path) -> dict[str, tuple[tuple[float, float, float, float], float]]:
    """A BOP scene_camera.json: frame number -> ((fx, fy, cx, cy), depth_scale)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return {
            str(int(k)): (
                (v["cam_K"][0], v["cam_K"][4], v["cam_K"][2], v["cam_K"][5]),
                float(v.get("depth_scale", 1.0)),
            )
            for k, v in data.items()
        }
    except (OSError, ValueError, KeyError, TypeError, IndexError) as e:
        raise UserError(f"{path} is not a BOP scene_camera.json ({e})") from None


def _state(args: argparse.Namespace):
    """The service's state on the data dir, as `posedesc serve` loads it (no demo objects added)."""
    if not args.data_dir.is_dir():
        raise UserError(f"no such data dir: {args.data_dir} (the service's, with the objects registered)")
    from index.features.embed import load_models, store_keys
    from index.store import EMBEDDED, StoreError
    from service.settings import Settings
    from service.state import load_state

    settings = Settings(data_dir=args.data_dir, models_dir=args.models, demo_objects=False)
    if not args.models.is_dir():
        raise UserError(f"no such models folder: {args.models}")
    say(f"loading the models of {args.models} and the objects of {args.data_dir} ...")
    embedders = load_models(args.models, settings.threads)
    if settings.store == EMBEDDED:
        same_models(args.data_dir, store_keys(embedders), args.models)
    try:
        state = load_state(settings, embedders)
    except StoreError as e:  # a damaged store.sqlite: one line, as build-index and serve say it
        raise UserError(str(e)) from None
    objects = state.store.snapshot.objects
    if not objects:
        raise UserError(f"{args.data_dir} holds no registered object: register some (POST /objects)")
    say(f"{len(objects)} objects registered: {', '.join(sorted(o.name for o in objects.values()))[:200]}")
    state.ready.set()
    return state


def say(line: str) -> None:
    """A progress line on stderr (stdout holds the result) when it is a terminal, as tqdm's bars: a
    script reading stderr gets the one-line error alone."""
    if sys.stderr.isatty():
        print(line, file=sys.stderr, flush=True)
