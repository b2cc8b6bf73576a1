"""docs/answers.jpg: a real LM-O frame searched whole by the service (colour only, the camera alone: no
centre, no distance), each object found drawn at its template's pose (left) and at its fitted pose (right,
the pose fit: `service/pipeline/fit.py`), as `POST /recognize/draw` draws them.

    PYTHONPATH=. .venv/bin/python scripts/answers_picture.py --dataset ../shared/data/lmo --frame 808

The 7 LM-O objects are registered into a temporary store through the service's own registration; the
frame should be a test frame (808-969): nothing was chosen on them."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np

from evaluation.served import register_objects
from index.data.bop import BopDataset
from index.features.embed import load_models
from service.answers import drawing
from service.pipeline.context import Query
from service.settings import Settings
from service.state import AppState, close_state, load_state

ROOT = Path(__file__).resolve().parents[1]
#: the picture's width, px: two 640 px frames side by side, halved to keep the file small
WIDTH = 1280


def drawn(state: AppState, q: Query) -> np.ndarray:
    """The frame as `POST /recognize/draw` answers it (every object found at its best answer), RGB."""
    png = drawing(state, q, 1)
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", type=Path, required=True)
    p.add_argument("--frame", type=int, default=808)
    p.add_argument("--scene", type=int, default=2)
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "answers.jpg")
    p.add_argument("--objects", help="dataset ids to register, comma-separated (default: all)")
    args = p.parse_args()
    dataset = BopDataset(args.dataset)
    frame = next(i for i in dataset.instances(args.scene) if i.frame_id == args.frame)
    rgb_path = args.dataset / "test" / f"{args.scene:06d}" / "rgb" / f"{args.frame:06d}.png"
    K = frame.K
    q = Query(rgb_path.read_bytes(), None, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], k=1)
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=Path(tmp), demo_objects=False, models_dir=ROOT / "models")
        state = load_state(settings, load_models(ROOT / "models"))
        try:
            ids = [int(o) for o in args.objects.split(",")] if args.objects else dataset.obj_ids
            register_objects(state, dataset, ids)
            state.settings = settings.model_copy(update={"pose_fit": 0})
            before = drawn(state, q)
            state.settings = settings
            after = drawn(state, q)
        finally:
            close_state(state)
    both = np.hstack([before, np.full((before.shape[0], 8, 3), 255, np.uint8), after])
    scale = WIDTH / both.shape[1]
    small = cv2.resize(both, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    # JPEG at 85: a photograph, a fifth of the PNG's bytes
    cv2.imwrite(str(args.out), cv2.cvtColor(small, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"{args.out}: {small.shape[1]} x {small.shape[0]} px, {args.out.stat().st_size:,} bytes")


if __name__ == "__main__":
    main()
