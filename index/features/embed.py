"""The ONNX embedder: patches -> descriptors with onnxruntime. Everything the patch pipeline needs to
prepare the network's input (modality, window, size) is read from the model's own metadata, so the
service, the evaluation and training can never disagree about it."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnx.numpy_helper
import onnx.shape_inference
import onnx.utils
import onnxruntime as ort

from index.features.patches import MODALITY_CHANNELS, PatchSpec, batch_inputs

INPUT_NAME, OUTPUT_NAME = "patch", "descriptor"
#: A second output some models have: the L2-normalised feature map of their pretrained trunk, flattened,
#: for re-ranking the nearest answers by local similarity (`service.recognition`, `index.store`).
LOCAL_NAME = "local"
#: A third output some models have: logits (N, 1, S, S) of the pixels of the object at the patch's centre
#: (a head on the trunk, `training/heads/mask.py`, or an RGB-D model's depth, `training.export`): the
#: re-ranking compares a query with a template where they are positive (`index.features.local`).
MASK_NAME = "mask"


@dataclass(frozen=True)
class ModelInfo:
    """What a descriptor model says about itself (ONNX metadata_props)."""

    modality: str
    window_mm: float
    size: int
    descriptor_dim: int
    extra: dict[str, str]

    @property
    def spec(self) -> PatchSpec:
        return PatchSpec(self.size, self.window_mm)

    @property
    def inplane_step(self) -> float:
        """Degrees between the in-plane variants the model was trained to tell apart over the whole turn
        (metadata `inplane_step`); 0 for a model trained on upright views only (a legacy model)."""
        return float(self.extra.get("inplane_step") or 0.0)

    def to_metadata(self) -> dict[str, str]:
        return {
            "modality": self.modality,
            "window_mm": str(self.window_mm),
            "size": str(self.size),
            "descriptor_dim": str(self.descriptor_dim),
            "normalisation": "rgb: per-channel zero mean, unit variance; depth: (d - surface depth at "
            "centre) / (window/2) clipped to [-1, 1], empty = +1 (index/features/patches.py)",
            **self.extra,
        }

    @classmethod
    def from_metadata(cls, meta: dict[str, str]) -> ModelInfo:
        known = {"modality", "window_mm", "size", "descriptor_dim", "normalisation"}
        try:
            info = cls(
                modality=meta["modality"],
                window_mm=float(meta["window_mm"]),
                size=int(meta["size"]),
                descriptor_dim=int(meta["descriptor_dim"]),
                extra={k: v for k, v in meta.items() if k not in known},
            )
            step = info.inplane_step
        except KeyError as e:
            raise ValueError(f"not a posedesc model: metadata lacks {e}") from None
        except ValueError as e:
            raise ValueError(f"not a posedesc model: bad metadata ({e})") from None
        if not 0.0 <= step < 360.0:
            raise ValueError(f"not a posedesc model: inplane_step {step:g} is not in [0, 360)")
        return info


class Embedder:
    """Descriptors of patches with one ONNX model. Thread-safe (onnxruntime sessions are).

    A model with several outputs (descriptor, `LOCAL_NAME`, `MASK_NAME`) is run as one session per
    output, each pruned to the nodes its output needs: onnxruntime runs the whole graph whatever outputs
    are asked for (onnxruntime issue 16483), and the mask head costs about eight times the trunk alone, so asking
    the shipped rgb model for local features alone took 1.7 ms a patch instead of 0.2."""

    def __init__(self, path: str | Path, threads: int | None = None):
        self.path = Path(path)
        opts = ort.SessionOptions()
        # Two cores here: one intra-op thread per call by default, so concurrent requests each get a
        # core instead of fighting over both; `threads` changes it (the service: its setting `threads`).
        opts.intra_op_num_threads = threads or 1
        opts.inter_op_num_threads = 1
        try:
            model = onnx.load(str(self.path))
            meta = {p.key: p.value for p in model.metadata_props}
            #: what the model computes, whatever its metadata says (a calibration names the graph it was
            #: measured on: `service.rejection`)
            self.graph_digest = graph_digest(model)
            outputs = [o.name for o in model.graph.output]
            parts = {outputs[0]: model} if len(outputs) == 1 else _per_output(model, outputs)
            #: nodes of each output's graph
            self.nodes = {name: len(m.graph.node) for name, m in parts.items()}
            self.sessions = {
                name: ort.InferenceSession(m.SerializeToString(), opts, providers=["CPUExecutionProvider"])
                for name, m in parts.items()
            }
        except Exception as e:
            raise ValueError(f"cannot load ONNX model {self.path}: {_first_line(e)}") from None
        self.info = ModelInfo.from_metadata(meta)
        if OUTPUT_NAME not in self.sessions:
            raise ValueError(f"not a posedesc model: {self.path} has no {OUTPUT_NAME!r} output")
        self.has_local, self.has_mask = LOCAL_NAME in self.sessions, MASK_NAME in self.sessions
        #: cells on a side of the `local` map (metadata `local_grid`; the trunk's map is a quarter of the
        #: input's side)
        self.local_grid = int(self.info.extra.get("local_grid") or self.info.size // 4)
        if self.info.modality not in MODALITY_CHANNELS:
            raise ValueError(f"model {self.path} has unknown modality {self.info.modality!r}")
        self._probe: tuple[np.ndarray, np.ndarray | None] | None = None

    def probe(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Its descriptors and local features of a fixed random colour input (the first three channels
        of seeded noise; depth channels of the same noise where the model takes them): equal for two
        models when they describe colour alike whatever else they read (`same_templates`)."""
        if self._probe is None:
            s, channels = self.info.size, MODALITY_CHANNELS[self.modality]
            x = np.random.default_rng(0).uniform(-2.0, 2.0, (4, 4, s, s)).astype(np.float32)
            x = x[:, 4 - channels :] if channels < 3 else x[:, :channels]  # depth alone: the last channel
            self._probe = (self(x), self._run(LOCAL_NAME, x) if self.has_local else None)
        return self._probe

    def same_templates(self, other: Embedder) -> bool:
        """Whether `other` makes the same templates as this model: same window, size, in-plane step and
        descriptor size, both reading colour, and the same descriptors and local features of the probe
        (`probe`). The RGB-D model written from the rgb run (`posedesc export --as-rgbd`) is the rgb
        network on the colour channels, its mask from depth: registration embeds its templates once."""
        if {self.modality, other.modality} != {"rgb", "rgbd"}:
            return False
        if _template_shape(self) != _template_shape(other):
            return False
        (d1, l1), (d2, l2) = self.probe(), other.probe()
        if d1.shape != d2.shape or not np.allclose(d1, d2, atol=1e-5):
            return False
        return l1 is None or (l2 is not None and l1.shape == l2.shape and np.allclose(l1, l2, atol=1e-5))

    def _run(self, output: str, inputs: np.ndarray) -> np.ndarray:
        return self.sessions[output].run([output], {INPUT_NAME: np.ascontiguousarray(inputs, np.float32)})[0]

    @property
    def modality(self) -> str:
        return self.info.modality

    @property
    def dim(self) -> int:
        return self.info.descriptor_dim

    def __call__(self, inputs: np.ndarray, batch: int = 512) -> np.ndarray:
        """Network inputs (N, C, S, S) float32 -> descriptors (N, D) float32."""
        out = [self._run(OUTPUT_NAME, inputs[i : i + batch]) for i in range(0, len(inputs), batch)]
        return np.concatenate(out) if out else np.zeros((0, self.dim), np.float32)

    def local(self, inputs: np.ndarray, batch: int = 256) -> np.ndarray:
        """Network inputs (N, C, S, S) -> the model's local features (N, F) float16 (`LOCAL_NAME`)."""
        out = [
            self._run(LOCAL_NAME, inputs[i : i + batch]).astype(np.float16)
            for i in range(0, len(inputs), batch)
        ]
        return np.concatenate(out) if out else np.zeros((0, 0), np.float16)

    def mask(self, inputs: np.ndarray, batch: int = 256) -> np.ndarray:
        """Network inputs (N, C, S, S) -> where the centred object is (N, S, S) bool (`MASK_NAME`)."""
        out = [self._run(MASK_NAME, inputs[i : i + batch])[:, 0] > 0.0 for i in range(0, len(inputs), batch)]
        s = self.info.size
        return np.concatenate(out) if out else np.zeros((0, s, s), bool)

    def embed_patches(
        self,
        rgb: np.ndarray | None,
        depth: np.ndarray | None,
        nominal_mm: float | np.ndarray,
        fill: bool = True,
        local: bool = False,
        window_mm: float | None = None,
        batch: int | None = None,
    ) -> np.ndarray:
        """Cropped patches (rgb (N, S, S, 3) uint8, depth (N, S, S) mm) -> descriptors (N, D), or with
        `local` the local features (N, F) instead. `window_mm`: the window they were cut through (an
        object's class, `index.templates.windows`), which depth is normalised by; None: the model's. `batch`:
        patches per run (None: `__call__`'s and `local`'s own)."""
        window = self.info.window_mm if window_mm is None else window_mm
        x = batch_inputs(self.modality, rgb, depth, nominal_mm, window, fill)
        if batch is None:
            return self.local(x) if local else self(x)
        return self.local(x, batch) if local else self(x, batch)


def _template_shape(e: Embedder) -> tuple:
    """What two models must share for their templates to be interchangeable, before their outputs."""
    i = e.info
    return i.window_mm, i.size, i.descriptor_dim, i.inplane_step, e.has_local, e.local_grid


def _per_output(model: onnx.ModelProto, outputs: list[str]) -> dict[str, onnx.ModelProto]:
    """The model cut into one model per output, each holding only the nodes that output needs (and its
    concatenated convolution inputs padded: `pad_concat_channels`)."""
    extractor = onnx.utils.Extractor(model)
    return {name: pad_concat_channels(extractor.extract_model([INPUT_NAME], [name])) for name in outputs}


#: onnxruntime's blocked convolutions (NCHWc) take inputs whose channels are a multiple of this
CHANNEL_BLOCK = 8


def pad_concat_channels(model: onnx.ModelProto) -> onnx.ModelProto:
    """The model with each concatenation that feeds only convolutions (group 1, weights in the model)
    widened to a multiple of `CHANNEL_BLOCK` channels by zero channels (its last input times 0, repeated),
    and those convolutions' weights by zero rows: the same outputs, exactly (a zero channel times a zero
    weight). onnxruntime runs a convolution whose input channels are not a multiple of 8 through its
    generic kernel: the mask head's two such convolutions (image coordinates concatenated to 24 + 32 +
    64 and 48 + 16 channels) took 2.4 of its 5.9 ms a patch, and 1.4 padded (its profiler, one thread,
    here). A model without such a pattern is returned as it is."""
    try:
        shapes = onnx.shape_inference.infer_shapes(model).graph.value_info
    except Exception:  # a graph shape inference cannot read: left as it is
        return model
    channels = {v.name: d[1].dim_value for v in shapes if len(d := v.type.tensor_type.shape.dim) == 4}
    weights = {i.name: i for i in model.graph.initializer}
    outputs = {o.name for o in model.graph.output}
    consumers: dict[str, list[onnx.NodeProto]] = {}
    for n in model.graph.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)

    def widened(node: onnx.NodeProto) -> int:
        """Zero channels to append to a concatenation's output (0: none, or not padded)."""
        users, total, last = (
            consumers.get(node.output[0], []),
            channels.get(node.output[0], 0),
            channels.get(node.input[-1], 0),
        )
        axis = next((onnx.helper.get_attribute_value(a) for a in node.attribute if a.name == "axis"), None)
        convs = all(
            u.op_type == "Conv"
            and u.input[1] in weights
            and all(a.name != "group" or onnx.helper.get_attribute_value(a) == 1 for a in u.attribute)
            for u in users
        )
        if node.op_type != "Concat" or axis != 1 or not users or not convs or not total or not last:
            return 0
        if node.output[0] in outputs or any(len(consumers[u.input[1]]) > 1 for u in users):
            return 0  # seen outside the graph, or weights another node shares
        extra = -total % CHANNEL_BLOCK
        return -(-extra // last) * last

    out = onnx.ModelProto.FromString(model.SerializeToString())
    weights = {i.name: i for i in out.graph.initializer}
    nodes: list[onnx.NodeProto] = []
    for node in out.graph.node:
        if extra := widened(node):
            zero, zeros = f"{node.name}/pad_zero", f"{node.name}/pad_zeros"
            out.graph.initializer.append(onnx.numpy_helper.from_array(np.array(0.0, np.float32), zero))
            nodes.append(onnx.helper.make_node("Mul", [node.input[-1], zero], [zeros]))
            node.input.extend([zeros] * (extra // channels[node.input[-1]]))
            for conv in consumers[node.output[0]]:
                w = onnx.numpy_helper.to_array(weights[conv.input[1]])
                pad = np.zeros((w.shape[0], extra, *w.shape[2:]), w.dtype)
                weights[conv.input[1]].CopyFrom(
                    onnx.numpy_helper.from_array(np.concatenate([w, pad], 1), conv.input[1])
                )
        nodes.append(node)
    del out.graph.node[:], out.graph.value_info[:]
    out.graph.node.extend(nodes)
    return out


def _first_line(e: Exception) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


#: The shipped models' file names, by modality; a models folder holds any of them.
MODEL_FILES = {m: f"posedesc-{m}.onnx" for m in ("rgb", "depth", "rgbd")}


def load_models(models_dir: str | Path, threads: int | None = None) -> dict[str, Embedder]:
    """The models of `models_dir` by modality (whichever of `MODEL_FILES` exist; at least one)."""
    models_dir = Path(models_dir)
    found = {m: models_dir / f for m, f in MODEL_FILES.items() if (models_dir / f).is_file()}
    if not found:
        raise FileNotFoundError(
            f"no models in {models_dir}: expected any of {', '.join(MODEL_FILES.values())}"
        )
    models = {m: Embedder(p, threads) for m, p in found.items()}
    for m, e in models.items():
        if e.modality != m:
            raise ValueError(f"{e.path.name} is a {e.modality} model, not {m}")
    return models


def graph_digest(model: onnx.ModelProto) -> str:
    """Short sha256 of a model's graph: what it computes, whatever its metadata (a calibration) says."""
    return hashlib.sha256(model.graph.SerializeToString()).hexdigest()[:16]


def fingerprint(path: str | Path) -> str:
    """Short sha256 of a model file: templates made with one model are useless to another."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def store_key(e: Embedder) -> tuple[int, str]:
    """What a store files a model's templates under: its descriptor size and its graph's digest (what it
    computes: a new calibration rewrites the file's metadata and keeps the templates; stores made before
    were keyed by the whole file's `fingerprint` and make them once again), with the layout of what a
    template stores where that changed: a model with local features stores each template's relief too
    (`index.features.local.with_relief`), so a store's templates made before it are made again, as for a
    new model, rather than scored without it."""
    tag = e.graph_digest
    if e.has_local:
        tag = hashlib.sha256(f"{tag}:relief".encode()).hexdigest()[:16]
    return e.dim, tag


def store_keys(embedders: Mapping[str, Embedder]) -> dict[str, tuple[int, str]]:
    """`store_key` of each model, by modality: the `models` a store is opened with."""
    return {m: store_key(e) for m, e in embedders.items()}
