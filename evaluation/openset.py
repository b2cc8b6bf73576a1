"""Open-set answers through the service protocol: which object `recognise` puts first, and at what score,
when only some of the dataset's objects are registered.

Every object is registered once by the service's own registration (`evaluation.served`), into a real store
in a temporary folder; each registered set of a run is a copy of that store with the other objects removed
by the store's own removal (what `DELETE /objects/{id}` does), so "not registered" is exactly what a user
who never registered the object gets. Every instance of the frames is then sent to `recognise` as a user
sends it (`evaluation.queries.query`), with re-ranking on (the local-feature distance, when the model has
local features) and off (the descriptor distance)."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evaluation.progress import bar
from evaluation.queries import frame_files, query
from evaluation.samples import REAL, SYNTHETIC, needs_synthetic, select_instances
from evaluation.served import register_objects
from index.bop import BopDataset
from index.embed import Embedder
from service.errors import ApiError
from service.recognition import recognise
from service.settings import Settings
from service.state import AppState, close_state, load_state


@dataclass
class Answers:
    """One row per (registered set, instance): obj (its object), answered (the best answer's object, -1:
    refused), registered (its object was), run (index of the registered set), frame; and per score kind
    ("local", "descriptor") the best answer's distance."""

    obj: list[int] = field(default_factory=list)
    answered: dict[str, list[int]] = field(default_factory=dict)
    scores: dict[str, list[float]] = field(default_factory=dict)
    registered: list[bool] = field(default_factory=list)
    run: list[int] = field(default_factory=list)
    frame: list[int] = field(default_factory=list)

    def arrays(self, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(scores, right, registered, obj) of one score kind, refused queries left out."""
        a = np.array(self.answered[kind])
        keep = a >= 0
        obj = np.array(self.obj)
        return (
            np.array(self.scores[kind])[keep],
            (a == obj)[keep],
            np.array(self.registered)[keep],
            obj[keep],
        )


def score_kinds(embedder: Embedder) -> list[str]:
    """The kinds of score the service answers with for this model."""
    return ["local", "descriptor"] if embedder.has_local else ["descriptor"]


def collect(
    model: Path,
    dataset_dir: Path,
    frames: Sequence[int],
    registered_sets: Sequence[Sequence[int]],
    scene: int = 2,
    min_visib: float = 0.5,
    rerank: int = 200,
    seed: int = 0,
) -> Answers:
    """Every instance of `frames` through `recognise`, once per registered set (dataset object ids)."""
    dataset = BopDataset(dataset_dir)
    obj_ids = dataset.obj_ids
    instances = select_instances(dataset, scene, min_visib, frames, obj_ids)
    if not instances:
        raise ValueError(f"{dataset_dir}: no instance of scene {scene} in the frames asked for")
    with tempfile.TemporaryDirectory(prefix="posedesc-openset-") as tmp:
        base = Path(tmp) / "all"
        settings = Settings(data_dir=base, demo_objects=False, rerank=rerank, reject_above="off")
        embedder = Embedder(model, settings.threads)
        kinds = score_kinds(embedder)
        state = load_state(settings, {embedder.modality: embedder})
        try:
            _, dataset_ids = register_objects(state, dataset, obj_ids)
        finally:
            close_state(state)
        store_id = {o: s for s, o in dataset_ids.items()}
        synthetic = needs_synthetic(embedder.modality, instances)
        kind = SYNTHETIC if synthetic else REAL  # as before rendered depth came: scenes, or the frames
        sent = list(frame_files(dataset, instances, embedder.modality, kind, seed))
        out = Answers(answered={k: [] for k in kinds}, scores={k: [] for k in kinds})
        with bar(len(registered_sets) * len(instances), "recognise (open set)") as b:
            for run, subset in enumerate(registered_sets):
                folder = Path(tmp) / f"run{run}"
                shutil.copytree(base, folder)
                state = load_state(replace_dir(settings, folder), {embedder.modality: embedder})
                try:
                    for o in set(obj_ids) - set(subset):
                        state.store.remove_object(store_id[o])
                    _ask(state, sent, dataset_ids, kinds, set(subset), run, out, b.update)
                finally:
                    close_state(state)
                shutil.rmtree(folder)
    return out


def replace_dir(settings: Settings, data_dir: Path) -> Settings:
    return settings.model_copy(update={"data_dir": data_dir})


def _ask(state: AppState, sent, dataset_ids, kinds, subset: set[int], run: int, out: Answers, tick) -> None:
    with_local = state.settings
    without = with_local.model_copy(update={"rerank": 0})
    for group, rgb, depth, scale in sent:
        for inst in group:
            out.obj.append(inst.obj_id)
            out.registered.append(inst.obj_id in subset)
            out.run.append(run)
            out.frame.append(inst.frame_id)
            q = replace(query(inst, rgb, depth, scale), k=1)
            for kind in kinds:
                state.settings = with_local if kind == "local" else without
                try:
                    result = recognise(state, q)
                except ApiError:  # refused: counted apart, not as an answer
                    result = None
                if result is None or not result.matches or result.score != kind:
                    out.answered[kind].append(-1)
                    out.scores[kind].append(float("nan"))
                else:
                    m = result.matches[0]
                    out.answered[kind].append(dataset_ids[m.object_id])
                    out.scores[kind].append(m.distance)
            state.settings = with_local
            tick()
