"""The service's settings: one class, read from `POSEDESC_*` environment variables (and `posedesc serve`).

What a deployment may choose differently: where things live, what a request may ask, how much work a
recognition or a detection does and what it reports. A stage's tuned constants that nobody deploys
differently live in the stage's module with the measurement that chose them (`service/pipeline/`,
`service/detection/`); an experiment sets them in its own process."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

#: `Settings.shape_handicap`'s default
SHAPE_HANDICAP = 0.3


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="POSEDESC_", env_file=None, extra="ignore")

    # ---- Store and models: where the objects and the networks live (a deployment's choice) ----
    # The template store: "embedded" (SQLite + FAISS in data_dir, one process) or a Milvus URI as pymilvus
    # takes it (http://host:19530): replicas pointed at one Milvus and one shared data_dir serve one store.
    store: str = Field(
        "embedded", description="'embedded', or a Milvus URI (http://host:19530) replicas share"
    )
    data_dir: Path = Field(
        Path("data/default"),
        description="embedded store: SQLite + FAISS snapshots; Milvus store: the directory every replica "
        "shares for meshes, local features and job states",
    )
    store_prefix: str = Field(
        "posedesc", pattern=r"^[A-Za-z][A-Za-z0-9_]{0,60}$",
        description="Milvus store: its collections' name prefix (several stores on one Milvus)",
    )  # fmt: skip
    store_sweep_seconds: float = Field(
        600.0, gt=0, description="Milvus store: a registration pending this long was cut short; its "
        "templates are swept",
    )  # fmt: skip
    models_dir: Path = Field(Path("models"), description="posedesc-{rgb,depth,rgbd}.onnx, any of them")
    objectness_model: Path | None = Field(
        None, description="the objectness network colour frames without u and v are searched with "
        "(default: posedesc-objectness.onnx in models_dir)",
    )  # fmt: skip
    # LM-O validation frames, colour, whole frames: the model's nine quarter-octave levels against these five
    # half-octave ones, recall 79.1 -> 78.3, AP50 84.8 -> 86.4, found within 20 deg 53.0 -> 55.7, false a
    # frame 0.1 -> 0.1; the frame's median 314 -> 280 ms, proposals 79 -> 46 ms (docs/experiments.md)
    objectness_levels: list[Annotated[float, Field(gt=0, le=4)]] | None = Field(
        [1.0, 0.7071, 0.5, 0.3536, 0.25], description="the scales a colour frame is searched at by the "
        "objectness network (each a level of the pyramid); empty or null: the model's own",
    )  # fmt: skip

    # ---- Limits: what one request may ask of the machine (bad input gets a 4xx, never the memory) ----
    api_key: SecretStr | None = Field(None, description="when set, POST/DELETE /objects need it (X-API-Key)")
    allow_open_writes: bool = Field(
        False, description="without an API key on a non-loopback address, allow POST/DELETE /objects anyway"
    )

    max_image_mb: float = Field(25.0, gt=0, description="largest /recognize request body")
    max_mesh_mb: float = Field(50.0, gt=0, description="largest /objects request body")
    # Checked in the image header before decoding: a 20 kB PNG can claim to be 50000 x 50000 pixels.
    max_image_pixels: int = Field(4096 * 4096, gt=0, description="largest width x height accepted")
    max_faces: int = Field(200_000, gt=0, description="meshes above this are simplified to it")
    # A parse takes memory far beyond the file's size (6 M faces of OBJ fit in 48 MB and take 2 GB):
    max_upload_faces: int = Field(500_000, gt=0, description="meshes above this are refused (413)")
    max_k: int = Field(100, gt=0, description="largest k of /recognize")

    threads: int = Field(1, ge=1, description="onnxruntime intra-op and FAISS OpenMP threads per call")

    # ---- Recognition: a patch or a centre, each step's size as measured on the validation frames ----
    # In-plane (roll): by default each model's own metadata decides (`index.templates.register.TemplateConfig`):
    # templates over the whole turn for a model trained with roll, upright ones for a legacy model.
    inplane_step: float | None = Field(
        None, ge=0, lt=360, description="template in-plane step for every model, degrees (0: upright only); "
        "unset: each model's own (its metadata)",
    )  # fmt: skip
    inplane_max: float | None = Field(
        None, ge=0, le=360, description="template in-plane range +-, degrees (>= 180: the whole turn); "
        "unset: the whole turn for a model trained with roll, +-45 otherwise",
    )  # fmt: skip
    query_turns: int = Field(
        1, ge=1, le=36, description="cut the query this many times, turned by fractions of the templates' "
        "in-plane step (of the whole turn when upright only), and keep the best: finer roll, n embeddings",
    )  # fmt: skip
    # 400: chosen on the validation frames sent at five camera rolls (560 queries) among 200, 400, 600,
    # 1000 (docs/experiments.md: +2.9 points within 20 deg against 200; 600 and 1000 no better than 400)
    rerank: int = Field(
        400, ge=0, le=1000, description="with a model that has local features: re-rank this many nearest "
        "distinct answers by the local similarity of the query turned to each one's roll (0: off)",
    )  # fmt: skip
    # 150: chosen on the validation frames sent at five camera rolls among 0, 20, 60, 150, 400 (docs/experiments.md:
    # +4.5 points within 20 deg; 400 +4.6 at twice the work)
    roll_sweep: int = Field(
        150, ge=0, le=1000, description="re-ranking: compare this many best answers also at every other "
        "in-plane angle of the templates, and keep the roll that fits best (0: off)",
    )  # fmt: skip
    # YCB-V video 0000 (real depth, shape-only objects, centre given, the depth model): the first 5 re-ordered
    # by their fits, the right object 53 %; the first 20, each looked at coarsely
    # (`service.pipeline.fit.COARSE_ITERATIONS`), the best 3 then fitted fully (`fit.DEPTH_REFINE`), 95 %: the
    # mug's right pose was an answer past the fifth (docs/experiments.md). 122 -> 178 ms a query there
    depth_rerank: int = Field(
        20, ge=0, le=50, description="a frame with depth, its camera and a centre (the pose fit on): this many "
        "best answers are each fitted to the depth (coarsely) and re-ordered by the share of their points it "
        "explains plus their confidence; 0 or 1: not re-ordered",
    )  # fmt: skip
    # 1: the best answer, the one a user acts on (and each detection's); more costs a fit each
    pose_fit: int = Field(
        1, ge=0, le=100, description="refine the pose of this many best answers over all six degrees of "
        "freedom against the frame (a frame sent with its camera): the mesh's outline against the colour "
        "image, or its points against the depth (ICP); 0: off, every pose is a template's",
    )  # fmt: skip
    # chosen on LM-O's validation frames with YCB-V's 12 shape-only meshes registered beside (docs/experiments.md,
    # "Shape-only meshes beside textured ones")
    shape_handicap: float = Field(
        SHAPE_HANDICAP, ge=0, le=10, description="colour and RGB-D answers: a shape-only object's distance "
        "times 1 + this, in choosing the re-ranking's candidates and in the answer (its grey renders are near "
        "any colour patch: without it, it takes textured objects' names)",
    )  # fmt: skip
    # 5 (residuals clipped at 20 mm, `service.pipeline.score.RELIEF_CLIP_MM`): chosen on the RGB-D validation
    # frames sent at five camera rolls among 1, 3, 6, 10 unclipped, 3, 5, 8 clipped at 10 mm, 8, 12 at 6 mm
    # (docs/experiments.md: +14.8 points within 20 deg; 8 at 10 mm tied, the wider clip kept for real depth)
    relief_weight: float = Field(
        5.0, ge=0, le=100, description="re-ranking with depth: add this times the distance between the "
        "query's relief and a template's (rms of their cells' depth difference, in windows; 0: off)",
    )  # fmt: skip
    # A choice, not a measurement (docs/conventions.md): a patch has no camera, its answers are in the patch camera
    # on the optical axis, and a colour patch's object and rotation do not depend on this (the network reads
    # no distance from colour; the patch camera spans the window at any distance): only the answers' t does.
    # A depth patch without depth at its centre is also read against it (`index.features.patches.batch_inputs`)
    patch_distance_mm: float = Field(
        400.0, gt=0, le=100_000, description="a colour patch sent without distance_mm (and a depth patch "
        "without depth at its centre) is taken to be this far away, mm",
    )  # fmt: skip
    # A number replaces every model's calibrated threshold (`service.rejection`); "off": never reject. It
    # may be negative: the "lead" statistic (distance less a weight times the lead over another object) is
    reject_above: Annotated[float, Field(allow_inf_nan=False)] | Literal["off"] | None = Field(
        None, description="answer best = null when the best answer's statistic (the model's calibration "
        "says which: its distance, or its lead) is above this; 'off': never; unset: each model's "
        "calibration (its metadata `reject_above`), none without one",
    )  # fmt: skip
    level: int = Field(3, ge=0, le=4, description="template viewpoints: icosphere level (3 = 301)")
    # docs/experiments.md, "Every side for a shape-only mesh": YCB-V's shape-only objects are named more
    # often from every side; LM-O's scans stand as scanned
    viewpoints: Literal["upper", "sphere", "auto"] = Field(
        "upper", description="a registration that does not say: its templates seen from above the "
        "mesh's xy plane ('upper', the paper's half-sphere), from every side ('sphere': twice the templates, "
        "fewer for a shape that turns over onto itself), or 'auto': every side for a shape-only mesh (a CAD "
        "file's axes say nothing of how it lies), the upper half for a mesh with colours (a scan stands as "
        "it was scanned)",
    )  # fmt: skip
    index_kind: Literal["auto", "flat", "ivf"] = Field(
        "auto", description="auto = exact below `ivf_min_templates`, IVF from there; flat = always exact; ivf"
    )
    # 50,000: measured at 100 objects (docs/experiments.md): the search stage over 357,648 32-d
    # templates 5.28 ms exact, 1.72 ms IVF (256 lists, 16 probed), the same accuracy on the validation
    # frames. The threshold itself is a choice, not a measurement: the exact search's cost grows with the
    # templates, so a seventh of those is a few tenths of a ms to win
    ivf_min_templates: int = Field(
        50_000, ge=1, description="embedded store, index_kind auto: an IVF index from this many templates"
    )

    # ---- Detection: a frame without a centre (docs/detection.md; the real-depth floors' effect per video:
    # docs/experiments.md, leave-one-video-out) ----
    # Each proposal costs a run of the pipeline (~30 ms at 8 objects, 2 cores). The objectness network's
    # top 10 held 83 % of the validation instances within w/8 and 12 %, its top 20 83 % too
    # (docs/results/objectness-val.json). Verified at their centres, on the validation frames (recall /
    # precision / AP50 / frame): 6 75.7 / 96.7 / 81.3 / 434 ms; 8 79.1 / 95.8 / 84.8 / 451 ms; 10 79.1 /
    # 93.8 / 84.4 / 521 ms; 15 and 20 79.1 / 88.3 and 85.8 / 83.0 and 82.0 / 731 and 917 ms
    detect_proposals: int = Field(
        8,
        ge=1,
        le=500,
        description="a frame without u and v: how many colour proposals are verified",
    )
    # A frame asked alone would use one of the two cores: its objectness network runs on two threads (153 ->
    # 88 ms a frame) and its places are verified two at a time (verify 237 -> 189 ms: the pipeline holds the
    # GIL in parts); answers unchanged (docs/experiments.md). Two frames asked at once already use both
    # cores, and the extra threads share them
    detect_threads: int = Field(
        2, ge=1, le=16, description="a frame without u and v: the objectness network's threads and the "
        "places verified at once; with u and v, the parts of a store of shape-only and textured objects asked "
        "at once (1: one core)",
    )  # fmt: skip
    # Depth segments rank worse than the network's proposals in clutter (the real Kinect frame: 5 of its 6
    # instances in the first 30 segments, 1 in the first 10; docs/results/depth_proposals.json)
    detect_depth_proposals: int = Field(
        30,
        ge=0,
        le=500,
        description="a frame without u and v, with depth: how many depth segments are verified",
    )
    # Chosen on the 20 validation frames (115 instances at least half visible, docs/experiments.md), colour,
    # the shipped models: 0.4 reported 3.9 detections a frame, 0.91 of them right (recall 0.62), the best
    # F1; 0.3: 5.0 a frame, 0.76 right (0.65); 0.5: 3.1, 0.97 (0.52)
    detect_floor: float = Field(
        0.4, ge=0, le=1, description="a frame without u and v and without min_confidence: the confidence a "
        "detection from a colour proposal needs to be reported (with depth; or colours not weighed)",
    )  # fmt: skip
    # With depth, the detections are not weighed (a depth proposal is reported on the open-set verdict, not
    # a confidence): one whose colours are farther than this from its object's is not reported. LM-O's
    # validation frames, real colour, rendered depth, RGB-D model: none 0.852 / 0.726 / 2.80 false a frame
    # with only absent objects registered; 0.3: 0.852 / 0.838 / 0.25; 0.25: 0.835 / 0.857 / 0.05; 0.2:
    # 0.826 / 0.905 / 0 (recall / precision / false; the most found at <= 0.2 false a frame, as in colour).
    # The same bound says whether a textured answer's colours are its object's where an RGB-D frame with a
    # centre is asked of each part of a mixed store (`service.pipeline.fit.best_part`)
    detect_colour_ceiling: float = Field(
        0.25, ge=0, le=2, description="a frame without u and v, with depth, without min_confidence: a "
        "detection whose colours are farther than this from its object's is not reported; with u and v, of a "
        "store of shape-only and textured objects, such an answer does not take the answer from the shape-only "
        "part's (2: no ceiling)",
    )  # fmt: skip
    # A colour frame's detection confidence is weighed by its colours (`service.detection.agree`). Chosen with
    # the weight and the allowance there (the most found at <= 0.2 false detections a frame where only objects
    # absent from the validation frames are registered; docs/experiments.md): 0.25 then; with colour proposals
    # verified at their centres, by the same rule (recall / precision / false a frame): 0.25 67.0 / 96.3 /
    # 0.0; 0.2 73.0 / 94.4 / 0.0; 0.15 79.1 / 93.8 / 0.10; 0.1 80.9 / 92.1 / 0.55
    detect_rgb_floor: float = Field(
        0.15, ge=0, le=1, description="a frame without u and v, without depth and without min_confidence: the "
        "confidence a detection needs to be reported, its colours weighed",
    )  # fmt: skip
    # The pose fit's score on depth is the share of the object's visible points the depth explains at the
    # fitted pose (`index.refine.depth.score_of`). Chosen on YCB-V video 0000 (real depth, the shape-only
    # objects registered; docs/experiments.md): 0.2 took precision 0.22 -> 0.37 at recall 0.667 -> 0.650
    detect_depth_fit_floor: float = Field(
        0.2, ge=0, le=1, description="a frame without u and v, with depth, without min_confidence: a detection "
        "whose pose fitted to the depth explains less than this share of its visible points is not reported "
        "(a part of a depth segment: `service.detection.report.PART_FIT_FLOOR`, if higher)",
    )  # fmt: skip

    # ---- Registration: how long POST /objects waits, and the demo objects of an empty data dir ----
    sync_seconds: float = Field(2.0, ge=0, description="POST /objects answers 201 within this, else 202")
    demo_objects: bool = Field(True, description="register the built-in demo shapes into an empty data dir")

    @field_validator("api_key", mode="before")
    @classmethod
    def _empty_key_is_none(cls, v: object) -> object:
        return None if v is None or (isinstance(v, str) and not v.strip()) else v


#: `POSEDESC_*` variables the project reads that are not settings (the compose files' image name)
NOT_SETTINGS = frozenset({"POSEDESC_IMAGE"})


def unknown_variables(environ: Mapping[str, str]) -> list[str]:
    """The `POSEDESC_*` names in `environ` that are no setting: the settings ignore them (`extra="ignore"`),
    so a misspelt name, or a setting that became a stage's constant (docs/experiments.md, "The live path
    holds what ships"), would otherwise change nothing without a word."""
    known = {f"POSEDESC_{name.upper()}" for name in Settings.model_fields} | NOT_SETTINGS
    return sorted(k for k in environ if k.upper().startswith("POSEDESC_") and k.upper() not in known)


class _StoreOnly(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="POSEDESC_", env_file=None, extra="ignore")

    store: str = Settings.model_fields["store"].default


def default_store() -> str:
    """The `store` setting (POSEDESC_STORE) alone, for a tool that opens a store without serving
    (`posedesc build-index`): another setting's bad value is no reason for it to fail."""
    return _StoreOnly().store
