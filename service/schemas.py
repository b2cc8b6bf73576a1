"""Response models: what a client gets back, with examples for /docs."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field
from pydantic.config import JsonDict

MATCH_EXAMPLE: JsonDict = {
    "object_id": 3,
    "name": "demo-robot",
    "azimuth": 126.0,
    "elevation": 31.7,
    "inplane": 0.0,
    "distance": 0.42,
    "confidence": 0.83,
    # a patch's answer: in the patch camera, 400 mm along its optical axis
    "R": [-0.809, -0.5878, 0.0, -0.3089, 0.4251, -0.8508, 0.5001, -0.6883, -0.5255],
    "t": [0.0, 0.0, 400.0],
    "refined": False,
    "template": {"azimuth": 126.0, "elevation": 31.7, "inplane": 0.0},
    "u": None,
    "v": None,
}


class TemplateOut(BaseModel):
    """The template an answer came from: its viewpoint and roll (degrees)."""

    azimuth: float
    elevation: float
    inplane: float


class MatchOut(BaseModel):
    """An answer: an object and its pose (degrees, see the pose conventions), from the nearest template of
    that (object, viewpoint); with `refined`, that pose fitted to the frame over six degrees of freedom
    (POSE_FIT): every pose field then gives the fitted pose, `template` the template's."""

    model_config = ConfigDict(json_schema_extra={"examples": [MATCH_EXAMPLE]})

    object_id: int
    name: str
    azimuth: float = Field(description="camera azimuth about the object's +z, from +x towards +y, degrees")
    elevation: float = Field(description="camera elevation above the object's xy plane, degrees")
    inplane: float = Field(
        description="estimated roll about the optical axis, counter-clockwise in the image, degrees in "
        "(-180, 180]: the template's in-plane angle plus the query turn it was found on"
    )
    distance: float = Field(
        description="L2 distance, smaller is closer: between descriptors, or with re-ranking (RERANK) between "
        "the local features. The order of `matches` is by the final score: with depth and a centre the "
        "nearest answers are fitted and re-ordered by the depth they explain, so it need not grow down the list"
    )
    confidence: float | None = Field(
        None,
        description="chance that this is the right object, from its distance: the share of best answers "
        "with that distance that were the right object on the model's validation frames, with the object "
        "registered half of the time (a logistic fit, `scripts/calibrate_reject.py`); null when the model "
        "has no calibration for this kind of distance",
    )
    R: list[float] = Field(
        min_length=9,
        max_length=9,
        description="the answer's rotation, model to camera, row-major 3x3 (BOP's cam_R_m2c; OpenCV camera "
        "axes: x right, y down, z forward): its viewpoint and in-plane angle seen along the ray through the "
        "object's centre. For a patch, in the patch's own camera (looking along its centre)",
    )
    t: list[float] = Field(
        min_length=3,
        max_length=3,
        description="the object's origin in the camera, mm (BOP's cam_t_m2c): along the ray through (u, v), "
        "at `distance_mm` when sent; else at the surface measured at the centre plus this answer's offset "
        "(how far its object's origin lies behind the surface seen from its viewpoint, kept per template "
        "at registration; objects registered before offsets were kept: the surface); else 400 for a "
        "colour patch",
    )
    refined: bool = Field(
        False,
        description="the pose was fitted to the frame (the mesh's outline against the colour image, or its "
        "points against the depth) and moved from its template's: azimuth, elevation, inplane, R, t, u and "
        "v then give the fitted pose (the angles along the ray through the fitted origin)",
    )
    template: TemplateOut = Field(description="the viewpoint and roll of the template the answer came from")
    u: float | None = Field(
        None, description="where the object's origin projects in the frame, px (null for a patch)"
    )
    v: float | None = None


class RleMask(BaseModel):
    """A mask as COCO writes a segmentation: compressed run-length encoding over the pixels in column-major
    order (pycocotools' `mask.decode` reads it)."""

    size: list[int] = Field(description="height, width of the frame, px")
    counts: str = Field(description="the runs, first of background, in COCO's compressed string")


class DetectionOut(BaseModel):
    """One object found in a whole frame."""

    u: float = Field(description="where the object's origin projects, px")
    v: float
    box: list[float] = Field(
        description="x0, y0, x1, y1 px: the object's mesh at its pose, clipped to the frame"
    )
    best: MatchOut = Field(description="the answer at (u, v): the object and its pose")
    matches: list[MatchOut] = Field(description="the k nearest distinct answers at (u, v), `best` first")
    confidence: float = Field(
        description="the detection's confidence, what `min_confidence` is compared with: the answer's, times "
        "the proposal's score and, in a colour frame, how well the frame's colours agree with the object's"
    )
    colour_distance: float | None = Field(
        None,
        description="0-2: how far the frame's colours where the object is are from its own (chromaticity, "
        "mean L1); null when not measured (no colour image, an object without colours)",
    )
    mask: RleMask | None = Field(
        None, description="the object's mesh at its pose in the frame, as COCO's compressed RLE (pycocotools)"
    )


class RecognizeOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "matches": [MATCH_EXAMPLE],
                    "best": MATCH_EXAMPLE,
                    "reason": None,
                    "score": "local",
                    "timings_ms": {
                        "decode": 2.1,
                        "cut": 0.6,
                        "mask": 1.2,
                        "embed": 0.5,
                        "search": 2.4,
                        "local": 9.8,
                        "sweep": 5.3,
                        "refine": 4.1,
                        "patch": 1.8,
                        "rerank": 19.2,
                        "total": 26.0,
                    },
                    "model": "posedesc-rgb",
                }
            ]
        }
    )

    matches: list[MatchOut] = Field(
        description="the k best distinct (object, viewpoint) answers, best first (nearest first, but with "
        "depth and a centre, re-ordered by the depth each explains at its fitted pose): the in-plane "
        "variants of a viewpoint count once, at their nearest"
    )
    best: MatchOut | None = Field(
        description="the nearest answer; null when no object is registered or when it is not close enough "
        "(its distance above the model's calibrated threshold or the REJECT_ABOVE setting): `reason` says"
    )
    reason: str | None = Field(None, description="why `best` is null; null when it is not")
    score: str = Field(
        "descriptor",
        description="what the matches' distances are: 'local' (re-ranked) or 'descriptor'",
    )
    colour_distance: float | None = Field(
        None,
        description="a colour frame sent with its camera and the object's centre: how far the frame's colours "
        "where the first answer's pose puts its object are from that object's (chromaticity, mean L1, 0-2; "
        "its own colours: about 0.1, another object's: 0.3 and more); with the model's calibration it is "
        "part of the open-set verdict (`reason` says so). null: not measured (a patch, a shape-only object, "
        "too little of it in view)",
    )
    unexplained: float | None = Field(
        None,
        description="a frame sent with its depth, its camera and the object's centre: the share of the first "
        "answer's surface at its pose that the depth could show and does not explain (0-1: its own surface "
        "about 0.1, another object's 0.5 and more; points behind a nearer object or over a hole in the depth "
        "are left out); with the model's calibration it is part of the open-set verdict. null: not measured",
    )
    timings_ms: dict[str, float] = Field(
        description="milliseconds of each stage that ran (`service.pipeline`): decode (the images), cut (the "
        "patch at each query turn), mask (models with a mask), embed (the descriptors), search (the store), "
        "local (the re-ranking by local features), sweep (the roll sweep), refine (viewpoints and rolls "
        "around the best), fit (the pose fit), colours (the colours at the first answer's pose); then sums kept for older readers: patch = cut + mask, rerank = local + sweep + "
        "refine (present when the re-ranking ran); total (all of it)"
    )
    model: str = Field(description="the model that matched the modality sent")
    detections: list[DetectionOut] | None = Field(
        None,
        description="a frame sent without u and v: every registered object found in it, most confident "
        "first (at most max_detections); `best` and `matches` are then the first detection's. Null when u "
        "and v were sent",
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="what the service could not do for this query and you should know: a whole colour frame "
        "names the shape-only objects (meshes without colours) it does not search for",
    )


class ObjectOut(BaseModel):
    object_id: int
    name: str
    symmetry: str
    faces: int
    templates: dict[str, int] = Field(description="templates per model")
    created: float = Field(description="unix time")
    demo: bool = Field(
        False,
        description="a demo object the service registered itself into a new data dir (a generated shape); "
        "it answers for your frames too: DELETE it (it does not come back), or start a new data dir with "
        "POSEDESC_DEMO_OBJECTS=false",
    )
    diameter_mm: float | None = Field(
        None, description="the object's diameter as registered, mm (None: registered before it was kept)"
    )
    window_mm: float = Field(description="the patch window the object is seen through, mm (its size's class)")
    textured: bool | None = Field(
        None, description="its mesh has colours; false: shape only (None: registered before it was kept)"
    )
    symmetry_from: str | None = Field(
        None,
        description="'given' (asked for), 'shape' (found from a shape-only mesh) or 'colours' (a "
        "textured mesh: none)",
    )
    viewpoints: str | None = Field(
        None,
        description="'upper' (its templates seen from above its mesh's xy plane) or 'sphere' (from every "
        "side); None: registered before it was kept (upper)",
    )


class ObjectCreated(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "object_id": 5,
                    "name": "my-part",
                    "templates": 301,
                    "seconds": 1.84,
                    "timings": {"render": 1.3, "embed": 1.1, "store": 0.04, "total": 1.84},
                    "diameter_mm": 163.2,
                    "window_mm": 200.0,
                    "symmetry": "none",
                    "textured": True,
                    "symmetry_from": "colours",
                    "viewpoints": "upper",
                    "warnings": [],
                }
            ]
        }
    )

    object_id: int
    name: str
    templates: int = Field(description="templates added per model (viewpoints x in-plane steps)")
    seconds: float = Field(description="time the registration took")
    timings: dict[str, float] = Field(description="seconds rendering, embedding (they overlap), storing")
    # None only in the result of a job saved before they were reported
    diameter_mm: float | None = Field(
        None, description="the object's diameter as read in the file's units, mm"
    )
    window_mm: float | None = Field(
        None,
        description="the patch window chosen for its size, mm: the model's for objects about its size, "
        "larger or smaller steps of sqrt(2) for others",
    )
    symmetry: str | None = Field(None, description="the symmetry it was registered with")
    textured: bool | None = Field(None, description="its mesh has colours; false: shape only")
    symmetry_from: str | None = Field(
        None, description="'given', 'shape' (found from a shape-only mesh) or 'colours' (textured: none)"
    )
    viewpoints: str | None = Field(
        None, description="'upper' (templates seen from above its mesh's xy plane) or 'sphere' (every side)"
    )
    warnings: list[str] = Field(default_factory=list)


class ObjectsRemoved(BaseModel):
    removed: list[int] = Field(description="the ids of the objects removed")


class JobAccepted(BaseModel):
    job_id: str
    status: str = "running"


class JobProgress(BaseModel):
    """How far a registration is. The object's views are rendered and embedded in chunks, so the stages
    alternate (render, embed, render, ...), then its templates are stored at once."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"stage": "embed", "done": 1806, "total": 3612}]}
    )

    stage: Literal["render", "embed", "store"] = Field(
        description="what it is doing now: rendering the next chunk of views, embedding one, storing"
    )
    done: int = Field(
        description="render, embed: the object's views done (rendered and embedded by every model; a view "
        "is a viewpoint at one in-plane angle); store: templates stored (0 while storing, then `total`)"
    )
    total: int = Field(description="how many views (render, embed) or templates (store) there are")


class JobOut(BaseModel):
    job_id: str
    status: str = Field(description="running | done | failed")
    object_id: int | None = None
    result: ObjectCreated | None = None
    error: str | None = None
    code: int | None = Field(
        None, description="a failed job's HTTP status, as POST /objects would have answered"
    )
    progress: JobProgress | None = Field(
        None, description="how far it is (null until the first chunk of views is rendered)"
    )


class ErrorOut(BaseModel):
    """Every error: one line saying what is wrong."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"detail": "no object 7"}]})

    detail: str


class Health(BaseModel):
    status: str


class Ready(BaseModel):
    status: str = Field(description="ready | starting | unavailable (the template store does not answer)")
    models: dict[str, str] = Field(description="modality -> model name")
    objects: int
    templates: dict[str, int]
    detail: str | None = None
    calibration: dict[str, str] = Field(
        default_factory=dict,
        description="modality -> how its model's open-set calibration (threshold, confidences) was made "
        "with other settings than the running ones; empty when every one matches",
    )
