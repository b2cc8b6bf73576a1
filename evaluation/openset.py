"""Open-set answers through the service protocol: which objects `recognise` answers, and at what scores,
when only some of the dataset's objects are registered.

Every object is registered once by the service's own registration (`evaluation.served`), into a real store
in a temporary folder; each registered set of a run is a copy of that store with the other objects removed
by the store's own removal (what `DELETE /objects/{id}` does), so "not registered" is exactly what a user
who never registered the object gets: the re-ranking's candidates, its roll sweep and its refinement all
run without the object, which filtering one collection's answers afterwards would not reproduce (measured:
`scripts/calibrate_reject.py --compare-filtered`). Every instance of the frames is then sent to `recognise`
as a user sends it (`evaluation.queries.query`) with the service's settings, with re-ranking on (the
local-feature distance, when the model has local features) and off (the descriptor distance). A dataset
without depth (LM-O) is sent with its real colour and depth rendered from the ground truth, as `posedesc
evaluate --protocol service` sends it (`evaluation.paper.samples.served_data`)."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Sequence
from contextlib import closing, nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evaluation.paper.samples import RENDERED, select_instances, served_data
from evaluation.progress import bar
from evaluation.queries import frame_files, query
from evaluation.served import register_objects
from index.data.bop import BopDataset
from index.features.embed import Embedder
from index.store import Match
from index.templates.render import Renderer
from service.errors import ApiError
from service.recognition import recognise
from service.rejection import LISTED as REJECT_LISTED
from service.rejection import Calibration, settings_of
from service.settings import Settings
from service.state import AppState, close_state, load_state

#: answers kept per query: the scores that look past the best answer (`service.rejection`) read the
#: best answer of another object among them
LISTED = 40


@dataclass
class Answers:
    """One row per (registered set, instance): obj (its object), registered (its object was), run (index of
    the registered set), frame; per score kind ("local", "descriptor") the answers' dataset object ids
    (n, LISTED), -1 past the last (a refused query has none) and their distances (n, LISTED), nan past the
    last. `settings`: what the answers were made with (`service.rejection.settings_of`); `data`: what
    the frames were (`evaluation.paper.samples.served_data`)."""

    obj: list[int] = field(default_factory=list)
    registered: list[bool] = field(default_factory=list)
    run: list[int] = field(default_factory=list)
    frame: list[int] = field(default_factory=list)
    objects: dict[str, list[list[int]]] = field(default_factory=dict)
    distances: dict[str, list[list[float]]] = field(default_factory=dict)
    settings: dict[str, dict[str, object]] = field(default_factory=dict)
    data: str = ""

    @property
    def kinds(self) -> list[str]:
        return list(self.objects)

    def lists(self, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """(object ids, distances), (n, LISTED) each, every row."""
        return np.array(self.objects[kind], int), np.array(self.distances[kind], float)

    def arrays(
        self, kind: str, statistic: Calibration | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(best answers' scores, right, registered, obj) of one score kind, refused queries left out; the
        score is `statistic`'s (`Calibration.values`, as the service computes it), else the distance."""
        ids, dist = self.lists(kind)
        keep = ids[:, 0] >= 0
        obj = np.array(self.obj)
        best = dist[:, 0] if statistic is None else best_values(ids, dist, statistic)
        return best[keep], (ids[:, 0] == obj)[keep], np.array(self.registered)[keep], obj[keep]

    def run_of(self, kind: str) -> np.ndarray:
        """Each answered row's registered set (the rows `arrays` keeps)."""
        return np.array(self.run)[self.lists(kind)[0][:, 0] >= 0]

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.__dict__))

    @classmethod
    def load(cls, path: Path) -> Answers:
        return cls(**json.loads(path.read_text()))


def best_values(ids: np.ndarray, dist: np.ndarray, statistic: Calibration) -> np.ndarray:
    """The best answer's `statistic` of each row of answer lists ((n, LISTED) ids and distances), computed
    by the service's own code on the answers the service listed; nan for a refused query."""
    out = np.full(len(ids), np.nan)
    for i, (row_ids, row_dist) in enumerate(zip(ids, dist, strict=True)):
        listed = [
            Match(int(o), "", 0.0, 0.0, 0.0, float(d))
            for o, d in zip(row_ids, row_dist, strict=True)
            if o >= 0
        ]
        if listed:
            out[i] = statistic.values(listed[:REJECT_LISTED])[0]
    return out


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
    settings: Settings | None = None,
    seed: int = 0,
) -> Answers:
    """Every instance of `frames` through `recognise`, once per registered set (dataset object ids), with
    `settings` (default: the service's, `POSEDESC_*`) but rejection off."""
    dataset = BopDataset(dataset_dir)
    obj_ids = dataset.obj_ids
    instances = select_instances(dataset, scene, min_visib, frames, obj_ids)
    if not instances:
        raise ValueError(f"{dataset_dir}: no instance of scene {scene} in the frames asked for")
    with tempfile.TemporaryDirectory(prefix="posedesc-openset-") as tmp:
        base = Path(tmp) / "all"
        given = settings or Settings()
        settings = given.model_copy(update={"data_dir": base, "demo_objects": False, "reject_above": "off"})
        embedder = Embedder(model, settings.threads)
        kinds = score_kinds(embedder)
        state = load_state(settings, {embedder.modality: embedder})
        try:
            meshes, dataset_ids = register_objects(state, dataset, obj_ids)
            made = {k: settings_of(settings, embedder, k) for k in kinds}
        finally:
            close_state(state)
        store_id = {o: s for s, o in dataset_ids.items()}
        kind = served_data(embedder.modality, instances, None)
        renderer = Renderer() if kind in RENDERED else None  # this thread's (EGL: a context a thread)
        with closing(renderer) if renderer else nullcontext():
            sent = list(
                frame_files(dataset, instances, embedder.modality, kind, seed, renderer, dict(meshes))
            )
        out = Answers(
            objects={k: [] for k in kinds}, distances={k: [] for k in kinds}, settings=made, data=kind
        )
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
            q = replace(query(inst, rgb, depth, scale), k=LISTED)
            for kind in kinds:
                state.settings = with_local if kind == "local" else without
                try:
                    result = recognise(state, q)
                except ApiError:  # refused: counted apart, not as an answer
                    result = None
                ids, dist = [-1] * LISTED, [float("nan")] * LISTED
                if result is not None and result.score == kind:
                    for i, m in enumerate(result.matches[:LISTED]):
                        ids[i], dist[i] = dataset_ids[m.object_id], float(m.distance)
                out.objects[kind].append(ids)
                out.distances[kind].append(dist)
            state.settings = with_local
            tick()
