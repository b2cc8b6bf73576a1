"""Register every mesh of a folder into a data dir, offline.

The same code path as POST /objects; a service already serving that data dir sees them after a restart.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from posedesc.cli import UserError, same_models


def _symmetry(text: str) -> str:
    """A --symmetry: "auto" or a name of `index.geometry.symmetry`, in its smallest form."""
    from index.geometry.symmetry import canonical

    if text == "auto":
        return text
    try:
        return canonical(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    from index.geometry.units import UNITS
    from index.templates.mesh import FORMATS_TEXT
    from service.settings import default_store

    p.add_argument("--meshes", type=Path, required=True, help=f"folder of meshes: {FORMATS_TEXT}")
    p.add_argument("--data-dir", type=Path, required=True,
                   help="the store to add them to (made if missing); for a Milvus store, the directory its replicas share")  # fmt: skip
    p.add_argument("--store", default=default_store(),
                   help="'embedded' or a Milvus URI, http://host:19530; POSEDESC_STORE sets the default")  # fmt: skip
    p.add_argument("--models", type=Path, default=Path("models"), help="folder of posedesc-*.onnx models")
    p.add_argument("--units", choices=UNITS, default=None,
                   help="units of the mesh files (not given: mm, but a file whose size would read as an "
                   "ordinary object's in other units is refused until they are given)")  # fmt: skip
    p.add_argument("--symmetry", type=_symmetry, default="none",
                   help="of every mesh: 'auto' (each shape-only mesh's found from its shape), 'none', '180', "
                   "'full', each with '+flip' ('180+flip': a box; see POST /objects)")  # fmt: skip
    p.add_argument("--inplane-step", type=float, default=None,
                   help="template in-plane step for every model, degrees (0: upright only; default: each "
                   "model's own metadata, as the service)")  # fmt: skip
    p.add_argument("--inplane-max", type=float, default=None,
                   help="in-plane range +-, degrees (>= 180: the whole turn; default as the service)")  # fmt: skip
    p.add_argument("--level", type=int, choices=range(6), default=3, metavar="0-5",
                   help="template viewpoints: icosphere level (3 = 301)")  # fmt: skip
    p.add_argument("--name", action="append", default=[], metavar="FILE=NAME",
                   help="the name a mesh file is registered under (its file name without the extension, or "
                   "the whole file name), e.g. obj_000001=ape; repeat for each; default: the file's stem")  # fmt: skip
    p.add_argument("--max-faces", type=int, default=200_000, help="meshes above this are simplified")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from index.features.embed import load_models, store_keys
    from index.store import EMBEDDED, StoreError, open_store
    from index.templates.mesh import FORMATS_TEXT, MESH_FORMATS, MeshError, load_mesh
    from index.templates.register import TemplateConfig, register
    from index.templates.render import RenderWorker
    from index.templates.windows import DIAMETER_KEY, WINDOW_KEY
    from service.pipeline.query import untextured
    from service.routes.objects import SHAPE_ONLY

    if not args.meshes.is_dir():
        raise UserError(f"--meshes {args.meshes}: not a folder")
    files = sorted(f for f in args.meshes.iterdir() if f.suffix.lstrip(".").lower() in MESH_FORMATS)
    if not files:
        raise UserError(f"no meshes ({FORMATS_TEXT}) in {args.meshes}")
    names = _names(args.name, files)
    embedders = load_models(args.models)
    if args.store == EMBEDDED:
        same_models(args.data_dir, store_keys(embedders), args.models)
    try:
        store = open_store(args.store, args.data_dir, store_keys(embedders))
    except StoreError as e:
        raise UserError(str(e)) from None
    present = {r.name for r in store.snapshot.objects.values()}
    window = min(e.info.window_mm for e in embedders.values())
    worker = RenderWorker(size=next(iter(embedders.values())).info.size, window_mm=window)
    cfg = TemplateConfig(args.level, args.inplane_step, args.inplane_max)
    added, failed, t0 = 0, [], time.perf_counter()
    try:
        with ThreadPoolExecutor(2) as pool:
            for f in tqdm(files, desc="register", unit="mesh", disable=None):
                name = names.get(f, f.stem)
                if name in present:
                    tqdm.write(f"{f.name}: {name} is already in the store, skipped")
                    continue
                try:
                    mesh = load_mesh(f, units=args.units, max_faces=args.max_faces, check_size=True)
                    reg = register(
                        mesh,
                        name,
                        args.symmetry,
                        worker=worker,
                        embedders=embedders,
                        store=store,
                        cfg=cfg,
                        pool=pool,
                    )
                    added += 1
                    extra = reg.record.extra
                    tqdm.write(
                        f"{f.name}: {name}, diameter_mm {extra[DIAMETER_KEY]}, window_mm {extra[WINDOW_KEY]}"
                    )
                    if untextured(reg.record):  # as POST /objects warns
                        tqdm.write(f"{f.name}: warning: {SHAPE_ONLY}")
                except MeshError as e:
                    failed.append(f"{f.name}: {e}")
    finally:
        worker.close()
        store.close()
    for line in failed:
        print(f"posedesc build-index: skipped {line}")
    print(
        f"{added} objects added to {args.data_dir} in {time.perf_counter() - t0:.1f} s "
        f"({len(present)} already there, {len(failed)} unusable); models {', '.join(sorted(embedders))}"
    )
    return 1 if failed else 0  # the usable ones are in; the status says not all were


def _names(given: list[str], files: list[Path]) -> dict[Path, str]:
    """The `--name FILE=NAME` pairs, by file; refuses (one line) a pair that names no mesh of the folder,
    a file named twice, or two files given one name."""
    by_key = {k: f for f in files for k in (f.name, f.stem)}
    out: dict[Path, str] = {}
    for pair in given:
        key, sep, name = pair.partition("=")
        if not sep or not key or not name.strip():
            raise UserError(f"--name {pair!r}: write FILE=NAME, e.g. obj_000001=ape")
        if key not in by_key:
            raise UserError(f"--name {pair!r}: no mesh {key!r} in the folder")
        f = by_key[key]
        if f in out:
            raise UserError(f"--name: {f.name} is named twice")
        out[f] = name.strip()
    taken = list(out.values())
    if len(set(taken)) < len(taken):
        raise UserError("--name: two meshes given one name")
    return out
