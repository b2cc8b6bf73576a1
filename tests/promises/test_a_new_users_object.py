"""What a new user meets, on a real server (`posedesc serve` on loopback, the shipped models, the demo objects):
their own mesh registered, its `posedesc render --patches` queries sent as written. Its patches, sent with the
window the JSON says, are answered as that object and never as another one with confidence; registered
shape-only beside the textured demo objects, it is found in a whole frame, and named with its centre and in its
patches, with colour and depth as with depth alone; deleted, it is never named again."""

from __future__ import annotations

import json
import subprocess

import httpx
import pytest
import trimesh
from service_helpers import ROOT, Server

pytestmark = pytest.mark.slow

MODELS = ROOT / "models"
PART = ROOT / "service" / "examples" / "part.ply"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    if not all((MODELS / f"posedesc-{m}.onnx").is_file() for m in ("rgb", "depth", "rgbd")):
        pytest.skip(f"no shipped models in {MODELS}")
    env = {"POSEDESC_DEMO_OBJECTS": "true", "POSEDESC_SYNC_SECONDS": "60"}
    with Server(tmp_path_factory.mktemp("newuser") / "data", MODELS, env) as s:
        s.wait_ready(timeout=300)
        yield s
        s.stop()


def queries(mesh_path, out) -> list[dict]:
    exe = ROOT / ".venv" / "bin" / "posedesc"
    r = subprocess.run(
        [str(exe), "render", str(mesh_path), "--patches", str(out)], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    return [json.loads((out / f"query-{i:02d}.json").read_text()) for i in range(4)]


def files(folder, q: dict, *keys: str) -> dict:
    return {k.removeprefix("patch_"): (q["files"][k], (folder / q["files"][k]).read_bytes()) for k in keys}


def register(server: Server, mesh: trimesh.Trimesh, path, name: str) -> dict:
    """The mesh written to `path` and registered through POST /objects (mm, no symmetry): its object."""
    mesh.export(path)
    r = httpx.post(
        f"{server.url}/objects",
        files={"mesh": (path.name, path.read_bytes())},
        data={"name": name, "units": "mm", "symmetry": "none"},
        timeout=120,
    )
    assert r.status_code == 201, r.text
    return r.json()


def test_a_small_part_s_patches_are_answered_through_its_window(server, tmp_path):
    small = trimesh.load(PART, process=False)
    small.apply_scale(0.45)  # ~67 mm: a 100 mm window, not the model's 200
    obj = register(server, small, tmp_path / "small.ply", "small-part")
    assert obj["window_mm"] == 100.0
    qs = queries(tmp_path / "small.ply", tmp_path / "q")
    assert all(q["patch"]["form"]["window_mm"] == 100.0 for q in qs)
    for q in qs:
        best = {}
        for keys in (("patch_rgb",), ("patch_depth",), ("patch_rgb", "patch_depth")):
            best[keys] = b = httpx.post(
                f"{server.url}/recognize",
                files=files(tmp_path / "q", q, *keys),
                data=q["patch"]["form"],
                timeout=60,
            ).json()["best"]
            assert b is None or b["name"] == "small-part" or b["confidence"] < 0.5, (keys, b)
        right = best[("patch_depth",)]
        assert right is not None and right["name"] == "small-part"
    httpx.delete(f"{server.url}/objects/{obj['object_id']}")


def test_a_shape_only_part_beside_textured_objects_is_found_with_colour_as_with_depth(server, tmp_path):
    mesh = trimesh.load(PART, process=False)
    bare = trimesh.Trimesh(mesh.vertices, mesh.faces)  # a CAD file: no colours
    obj = register(server, bare, tmp_path / "bare.ply", "bare-part")
    assert obj["textured"] is False
    oid = obj["object_id"]
    qs = queries(tmp_path / "bare.ply", tmp_path / "q")
    camera = {k: qs[0]["form"][k] for k in ("fx", "fy", "cx", "cy")}
    found = {"rgb+depth": 0, "depth": 0}
    for q in qs:
        for kind, keys in (("rgb+depth", ("rgb", "depth")), ("depth", ("depth",))):
            a = httpx.post(
                f"{server.url}/recognize", files=files(tmp_path / "q", q, *keys), data=camera, timeout=120
            ).json()
            found[kind] += any(d["best"]["name"] == "bare-part" for d in a["detections"])
    assert found["depth"] >= 3 and found["rgb+depth"] >= found["depth"], found
    named = {"rgb+depth": 0, "depth": 0}  # with its centre too: each part asked of its own model
    for q in qs:
        for kind, keys in (("rgb+depth", ("rgb", "depth")), ("depth", ("depth",))):
            a = httpx.post(
                f"{server.url}/recognize", files=files(tmp_path / "q", q, *keys), data=q["form"], timeout=120
            ).json()
            named[kind] += a["best"] is not None and a["best"]["name"] == "bare-part"
    assert named["depth"] >= 3 and named["rgb+depth"] >= named["depth"], named
    patched = {"rgb+depth": 0, "depth": 0}  # its patches (no camera): each part asked, the surer answering
    for q in qs:
        for kind, keys in (("rgb+depth", ("patch_rgb", "patch_depth")), ("depth", ("patch_depth",))):
            a = httpx.post(
                f"{server.url}/recognize",
                files=files(tmp_path / "q", q, *keys),
                data=q["patch"]["form"],
                timeout=120,
            ).json()
            hit = a["best"] is not None and a["best"]["name"] == "bare-part"
            assert not hit or a["model"] == "posedesc-depth", (kind, a["model"])  # never through grey renders
            patched[kind] += hit
    assert patched["depth"] >= 3 and patched["rgb+depth"] >= patched["depth"], patched
    assert httpx.delete(f"{server.url}/objects/{oid}").status_code == 204
    after = httpx.post(
        f"{server.url}/recognize",
        files=files(tmp_path / "q", qs[0], "rgb", "depth"),
        data=camera,
        timeout=120,
    ).json()
    assert all(d["best"]["name"] != "bare-part" for d in after["detections"])  # deleted: never named again


def test_a_deleted_object_s_colour_frames_are_answered_unknown_not_as_another(server, tmp_path):
    mesh = trimesh.load(PART, process=False)  # the example part, with its colours
    obj = register(server, mesh, tmp_path / "part.ply", "coloured-part")
    assert obj["textured"] is True
    qs = queries(tmp_path / "part.ply", tmp_path / "q")

    def asked(q: dict) -> dict:
        r = httpx.post(
            f"{server.url}/recognize", files=files(tmp_path / "q", q, "rgb"), data=q["form"], timeout=120
        )
        assert r.status_code == 200, r.text
        return r.json()

    before = [asked(q) for q in qs]
    assert sum(a["best"] is not None and a["best"]["name"] == "coloured-part" for a in before) >= 3, before
    assert all(a["colour_distance"] is not None for a in before if a["best"] is not None)
    assert httpx.delete(f"{server.url}/objects/{obj['object_id']}").status_code == 204
    after = [asked(q) for q in qs]
    # the frames hold an object nobody registered now: its colours are no demo object's
    assert all(a["best"] is None for a in after), [(a["matches"][0]["name"], a["reason"]) for a in after]
    assert all("colour distance" in a["reason"] or "lead" in a["reason"] for a in after)
