"""The app with its lifespan (`with TestClient(app)`): real models (untrained), store, renderer."""

from __future__ import annotations

import io
import shutil
import sqlite3

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient
from PIL import Image
from service_helpers import (
    K,
    created,
    depth_png,
    expected_templates,
    frame,
    frame_fields,
    make_t_shape,
    ply_bytes,
    png,
    register,
    service_settings,
    wait_ready,
)

from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import view_error
from service.main import create_app

TRUE_VIEW = View(azimuth=37.0, elevation=28.0, inplane=0.0, distance=600.0)  # between template viewpoints
UV = (400.0, 220.0)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("data")


@pytest.fixture(scope="module")
def client(data_dir, posedesc_models, l_shape, t_shape):
    with TestClient(create_app(service_settings(data_dir, posedesc_models))) as c:
        wait_ready(c)
        c.ids = {
            "L": register(c, l_shape, "L")["object_id"],
            "T": register(c, t_shape, "T", symmetry="none")["object_id"],
        }
        yield c


@pytest.fixture(scope="module")
def l_frame(renderer, l_shape):
    return frame(renderer, l_shape, TRUE_VIEW, UV, wall_mm=1500.0)


def test_recognise_a_full_colour_frame(client, l_frame):
    rgb, _ = l_frame
    r = client.post("/recognize", files={"rgb": ("f.png", png(rgb))}, data=frame_fields(UV, distance_mm=600))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["model"] == "posedesc-rgb"
    assert len(body["matches"]) == 5 and body["best"] == body["matches"][0]
    assert body["best"]["name"] == "L" and body["best"]["object_id"] == client.ids["L"]
    errors = [
        view_error(m["azimuth"], m["elevation"], TRUE_VIEW.azimuth, TRUE_VIEW.elevation)
        for m in body["matches"]
    ]
    assert min(errors) <= 20.0, errors
    # a frame with its camera: the best answer is also fitted to it (`fit`), and its colours there measured
    assert set(body["timings_ms"]) == {"decode", "cut", "patch", "embed", "search", "fit", "colours", "total"}
    assert body["colour_distance"] is not None and body["colour_distance"] < 0.2  # the L's own colours


@pytest.mark.parametrize("sent", ["rgbd", "depth"])
def test_recognise_with_depth_picks_that_model(client, l_frame, sent):
    rgb, depth = l_frame
    files = {"depth": ("d.png", depth_png(depth))}
    if sent == "rgbd":
        files["rgb"] = ("f.png", png(rgb))
    r = client.post("/recognize", files=files, data=frame_fields(UV, k=3))  # distance from the depth
    assert r.status_code == 200, r.text
    assert r.json()["model"] == f"posedesc-{sent}" and len(r.json()["matches"]) == 3
    assert r.json()["best"]["name"] == "L"


def test_recognise_a_patch(client, renderer, t_shape):
    view = View(200.0, 50.0, 0.0, 400.0)
    t = renderer.render(t_shape, [view])
    big = np.asarray(Image.fromarray(t.rgb[0]).resize((128, 128)))  # any square size spanning the window
    r = client.post("/recognize", files={"rgb": ("p.png", png(big))}, data={"k": "5"})
    assert r.status_code == 200, r.text
    assert r.json()["best"]["name"] == "T"
    errors = [view_error(m["azimuth"], m["elevation"], 200.0, 50.0) for m in r.json()["matches"]]
    assert min(errors) <= 20.0


def test_each_match_carries_its_pose_in_the_camera(client, l_frame):
    """A frame's answers are posed along the ray through (u, v) at the distance sent; a patch's in its own
    camera, on the optical axis at 400 mm: each R the answer's view turned onto that ray."""
    rgb, _ = l_frame
    frame_r = client.post(
        "/recognize", files={"rgb": ("f.png", png(rgb))}, data=frame_fields(UV, distance_mm=600)
    )
    patch_r = client.post("/recognize", files={"rgb": ("p.png", png(GREY))}, data={"k": "3"})
    through_uv = np.linalg.inv(K) @ np.array([*UV, 1.0])
    for r, ray, distance in (
        (frame_r, through_uv / np.linalg.norm(through_uv), 600.0),
        (patch_r, np.array([0, 0, 1.0]), 400.0),
    ):
        assert r.status_code == 200, r.text
        for m in r.json()["matches"]:
            R, t = np.reshape(m["R"], (3, 3)), np.asarray(m["t"])
            if m["refined"]:  # fitted to the frame: its angles are read along the ray through its origin
                ray = t / np.linalg.norm(t)
            want_R, want_t = view_to_pose(View(m["azimuth"], m["elevation"], m["inplane"], distance), ray)
            np.testing.assert_allclose(t, want_t, atol=1e-9)
            np.testing.assert_allclose(R, want_R, atol=1e-9)
            assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) > 0


def test_objects_list_get_delete(client, posedesc_models, renderer, l_shape, l_frame):
    objs = client.get("/objects").json()
    assert {o["name"] for o in objs} >= {"L", "T"}
    one = client.get(f"/objects/{client.ids['T']}").json()
    n = expected_templates(posedesc_models, "rgb")
    assert one["name"] == "T" and one["symmetry"] == "none" and one["templates"]["rgb"] == n
    extra = register(client, l_shape, "L-copy", symmetry="180")
    assert extra["templates"] < n and extra["seconds"] > 0 and set(extra["timings"]) >= {"render", "embed"}
    assert client.delete(f"/objects/{extra['object_id']}").status_code == 204
    assert client.get(f"/objects/{extra['object_id']}").status_code == 404
    assert client.delete(f"/objects/{extra['object_id']}").status_code == 404
    rgb, _ = l_frame
    r = client.post(
        "/recognize", files={"rgb": ("f.png", png(rgb))}, data=frame_fields(UV, distance_mm=600, k=100)
    )
    assert extra["object_id"] not in {m["object_id"] for m in r.json()["matches"]}


def _png16_rgb() -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.full((64, 64), 1000, np.uint16)).save(buf, format="PNG")
    return buf.getvalue()


def _jpeg(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="JPEG")
    return buf.getvalue()


GREY = np.full((64, 64, 3), 90, np.uint8)
FULL = frame_fields(UV, distance_mm=600)
BAD_RECOGNITIONS = {
    "nothing sent": ({}, {}, "send an `rgb`"),
    "not an image": ({"rgb": b"hello, not a picture"}, {}, "not an image"),
    "truncated png": ({"rgb": png(GREY)[:60]}, {}, "truncated or corrupt"),
    "16-bit as rgb": ({"rgb": _png16_rgb()}, {}, "16-bit"),
    "8-bit depth": ({"depth": png(np.full((64, 64), 100, np.uint8))}, {}, "8-bit"),
    "colour depth": ({"depth": png(GREY)}, {}, "colour"),
    "jpeg depth": ({"depth": _jpeg(GREY)}, {}, "16-bit PNG"),
    "sizes differ": (
        {"rgb": png(GREY), "depth": depth_png(np.full((32, 32), 500.0))},
        {},
        "64 x 64 px but depth is 32 x 32",
    ),
    "centre outside": ({"rgb": png(np.zeros((480, 640, 3), np.uint8))}, {**FULL, "u": "700"}, "outside"),
    "all-zero depth patch": ({"depth": depth_png(np.zeros((64, 64)))}, {}, "all zero"),
    "all-zero depth frame": (
        {"depth": depth_png(np.zeros((480, 640)))},
        frame_fields(UV, distance_mm=600),
        "all zero",
    ),
    "no depth at centre": ({"depth": depth_png(np.zeros((480, 640)))}, frame_fields(UV), "no depth around"),
    "k zero": ({"rgb": png(GREY)}, {"k": "0"}, "k:"),
    "k absurd": ({"rgb": png(GREY)}, {"k": "100000"}, "at most"),
    "k not a number": ({"rgb": png(GREY)}, {"k": "many"}, "k:"),
    "partial frame": ({"rgb": png(GREY)}, {"fx": "500", "u": "10"}, "missing: fy, cx, cy, v"),
    "colour frame, no distance": (
        {"rgb": png(np.zeros((480, 640, 3), np.uint8))},
        frame_fields(UV),
        "distance_mm",
    ),
    "non-square patch": ({"rgb": png(np.zeros((64, 80, 3), np.uint8))}, {}, "square"),
    "depth scale zero": ({"depth": depth_png(np.full((64, 64), 500.0))}, {"depth_scale": "0"}, "depth_scale"),
    "fx nan": ({"rgb": png(GREY)}, {**FULL, "fx": "nan"}, "fx"),
    "empty file": ({"rgb": b""}, {}, "empty"),
}


@pytest.mark.parametrize("case", list(BAD_RECOGNITIONS))
def test_bad_recognitions_get_422(client, case):
    files, data, message = BAD_RECOGNITIONS[case]
    r = client.post("/recognize", files={k: (f"{k}.png", v) for k, v in files.items()}, data=data)
    assert r.status_code == 422, r.text
    assert isinstance(r.json()["detail"], str) and message in r.json()["detail"]


def _ply_points_only() -> bytes:
    return b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"


def _stl_on_a_line() -> bytes:
    return b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 2 0 0\nendloop\nendfacet\nendsolid x\n"


def _in_cm() -> bytes:
    """The T (about 160 mm across) written in centimetres."""
    mesh = make_t_shape()
    mesh.apply_scale(0.1)
    return ply_bytes(mesh)


def _gltf_with_separate_buffers() -> bytes:
    files = trimesh.creation.box(extents=[100, 60, 40]).export(file_type="gltf")
    return files["model.gltf"]  # its buffers are other files of the export: an upload cannot bring them


BAD_MESHES = {
    "not a mesh": ("x.ply", b"\x00\x01garbage" * 50, {}, "mesh:"),
    "no faces": ("x.ply", _ply_points_only(), {}, "mesh:"),
    "degenerate": ("x.stl", _stl_on_a_line(), {}, "degenerate"),
    "unknown format": ("x.docx", b"hello", {}, "unsupported mesh format"),
    "too small to see": ("x.ply", ply_bytes(trimesh.creation.box(extents=[0.01] * 3)), {}, "too small"),
    "centimetres given as mm": ("x.ply", _in_cm(), {"units": "mm"}, "read in cm it is 1"),
    "glTF pointing at other files": ("x.gltf", _gltf_with_separate_buffers(), {}, "data URIs"),
    "no extension": ("mesh", b"hello", {}, "extension"),
    "bad units": ("x.ply", b"", {"units": "furlong"}, "units"),
    "bad symmetry": ("x.ply", b"", {"symmetry": "90"}, "symmetry"),
    "empty name": ("x.ply", b"", {"name": ""}, "name"),
}


@pytest.mark.parametrize("case", list(BAD_MESHES))
def test_bad_meshes_get_422(client, case):
    filename, content, data, message = BAD_MESHES[case]
    r = client.post("/objects", files={"mesh": (filename, content)}, data={"name": "bad", **data})
    assert r.status_code == 422, r.text
    assert message in r.json()["detail"]
    assert "bad" not in {o["name"] for o in client.get("/objects").json()}


def test_a_mesh_in_centimetres_registers_with_units_cm(client):
    r = client.post("/objects", files={"mesh": ("t.ply", _in_cm())}, data={"name": "T in cm", "units": "cm"})
    obj = created(client, r)
    assert obj["name"] == "T in cm" and obj["warnings"] == []
    assert client.delete(f"/objects/{obj['object_id']}").status_code == 204


def test_unknown_ids_get_404(client):
    assert client.get("/objects/999999").status_code == 404
    assert client.delete("/objects/999999").json() == {"detail": "no object 999999"}
    assert client.get("/jobs/nope").status_code == 404
    assert client.get("/objects/abc").status_code == 422


def test_health_ready_metrics(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz").json()
    assert ready["status"] == "ready" and ready["models"]["rgb"] == "posedesc-rgb"
    text = client.get("/metrics").text
    n = ready["templates"]["rgb"]
    assert f'posedesc_templates{{model="rgb"}} {float(n)}' in text
    assert 'posedesc_requests_total{method="POST",route="/objects",status="201"}' in text
    assert "posedesc_registration_seconds_bucket" in text
    assert client.get("/openapi.json").json()["paths"]["/recognize"]["post"]["summary"]


def test_metrics_count_and_time_every_answer(client):
    """`service.metrics.Observe`: each answered request counted by method, route template and status, and
    timed by route; a path no route takes is counted as `unmatched`."""

    def value(line_start: str) -> float:
        lines = [x for x in client.get("/metrics").text.splitlines() if x.startswith(line_start + " ")]
        return float(lines[0].split()[-1]) if lines else 0.0

    ok = 'posedesc_requests_total{method="POST",route="/recognize",status="200"}'
    refused = 'posedesc_requests_total{method="POST",route="/recognize",status="422"}'
    unmatched = 'posedesc_requests_total{method="GET",route="unmatched",status="404"}'
    timed = 'posedesc_request_seconds_count{route="/recognize"}'
    before = {k: value(k) for k in (ok, refused, unmatched, timed)}
    assert client.post("/recognize", files={"rgb": ("g.png", png(GREY))}).status_code == 200
    assert client.post("/recognize", data={"k": "5"}).status_code == 422  # no image
    assert client.get("/no/such/path").status_code == 404
    after = {k: value(k) for k in before}
    assert {k: after[k] - before[k] for k in before} == {ok: 1, refused: 1, unmatched: 1, timed: 2}


def test_api_key_and_upload_limits(tmp_path, posedesc_models, l_shape):
    settings = service_settings(
        tmp_path,
        posedesc_models,
        api_key="s3cret",
        max_mesh_mb=0.5,
        max_image_mb=0.2,
        max_image_pixels=1000 * 1000,
    )
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        files = {"mesh": ("l.ply", ply_bytes(l_shape))}
        assert c.post("/objects", files=files, data={"name": "L"}).status_code == 401
        r = c.post("/objects", files=files, data={"name": "L"}, headers={"X-API-Key": "wrong"})
        assert r.status_code == 401 and "API key" in r.json()["detail"]
        oid = register(c, l_shape, "L", headers={"X-API-Key": "s3cret"})["object_id"]
        assert c.delete(f"/objects/{oid}").status_code == 401
        assert c.get("/objects").status_code == 200  # reads need no key
        big = {"mesh": ("big.ply", b"x" * 600_000)}
        r = c.post("/objects", files=big, data={"name": "big"}, headers={"X-API-Key": "s3cret"})
        assert r.status_code == 413 and "limit" in r.json()["detail"]
        noise = np.random.default_rng(0).integers(0, 255, (400, 400, 3), np.uint8)
        assert c.post("/recognize", files={"rgb": ("n.png", png(noise))}).status_code == 413

        def chunks():  # no Content-Length: the limit is enforced while the body streams in
            yield b'--b\r\nContent-Disposition: form-data; name="rgb"; filename="x.png"\r\n\r\n'
            for _ in range(50):
                yield b"x" * 10_000

        r = c.post(
            "/recognize", content=chunks(), headers={"Content-Type": "multipart/form-data; boundary=b"}
        )
        assert r.status_code == 413
        bomb = io.BytesIO()  # a small file that claims 2000 x 2000 px
        Image.new("L", (2000, 2000)).save(bomb, format="PNG")
        assert len(bomb.getvalue()) < 50_000
        r = c.post("/recognize", files={"rgb": ("b.png", bomb.getvalue())})
        assert r.status_code == 413 and "pixels" in r.json()["detail"]
        assert c.delete(f"/objects/{oid}", headers={"X-API-Key": "s3cret"}).status_code == 204


def test_slow_registration_becomes_a_job(tmp_path, posedesc_models, t_shape):
    with TestClient(create_app(service_settings(tmp_path, posedesc_models, sync_seconds=0.0))) as c:
        wait_ready(c)
        r = c.post("/objects", files={"mesh": ("t.ply", ply_bytes(t_shape))}, data={"name": "T"})
        assert r.status_code == 202 and r.headers["location"] == f"/jobs/{r.json()['job_id']}"
        done = register(c, t_shape, "T2")  # follows its own job to the end
        assert done["templates"] == 71
        job = c.get(f"/jobs/{r.json()['job_id']}").json()
        assert job["status"] == "done" and job["object_id"] == job["result"]["object_id"]
        assert {o["name"] for o in c.get("/objects").json()} == {"T", "T2"}


def test_restart_keeps_state(tmp_path, posedesc_models, l_shape, l_frame):
    with TestClient(create_app(service_settings(tmp_path, posedesc_models))) as c:
        wait_ready(c)
        oid = register(c, l_shape, "L")["object_id"]
        gone = register(c, l_shape, "L-gone")["object_id"]
        assert c.delete(f"/objects/{gone}").status_code == 204
    with TestClient(create_app(service_settings(tmp_path, posedesc_models))) as c:
        wait_ready(c)
        assert [(o["object_id"], o["name"]) for o in c.get("/objects").json()] == [(oid, "L")]
        rgb, _ = l_frame
        r = c.post("/recognize", files={"rgb": ("f.png", png(rgb))}, data=frame_fields(UV, distance_mm=600))
        assert {m["object_id"] for m in r.json()["matches"]} == {oid}
    db = sqlite3.connect(tmp_path / "store.sqlite")
    assert db.execute("SELECT COUNT(*) FROM templates WHERE object_id = ?", (gone,)).fetchone()[0] == 0


def test_demo_objects_are_registered_once(tmp_path, posedesc_models):
    settings = service_settings(tmp_path, posedesc_models, demo_objects=True, level=1)
    with TestClient(create_app(settings)) as c:
        ready = wait_ready(c)
        names = {o["name"]: o["object_id"] for o in c.get("/objects").json()}
        assert set(names) == {"demo-mug", "demo-lamp", "demo-robot", "demo-duck"} and ready["objects"] == 4
        assert c.delete(f"/objects/{names['demo-duck']}").status_code == 204
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        assert {o["name"] for o in c.get("/objects").json()} == {
            "demo-mug",
            "demo-lamp",
            "demo-robot",
        }  # not again


def test_intrinsics_are_used(client, l_frame):
    """The same frame with a wrong focal length cuts a wrongly scaled patch: a different descriptor."""
    rgb, _ = l_frame
    good = client.post(
        "/recognize", files={"rgb": ("f.png", png(rgb))}, data=frame_fields(UV, distance_mm=600)
    )
    wrong = {**frame_fields(UV, distance_mm=600), "fx": str(K[0, 0] * 1.6), "fy": str(K[1, 1] * 1.6)}
    bad = client.post("/recognize", files={"rgb": ("f.png", png(rgb))}, data=wrong)
    assert bad.status_code == 200
    assert bad.json()["best"]["distance"] > good.json()["best"]["distance"]


def test_unexpected_errors_are_json_500(client, monkeypatch):
    import service.answers as route

    def broken(state, q):
        raise RuntimeError("a bug")

    monkeypatch.setattr(route, "recognise", broken)
    raw = TestClient(client.app, raise_server_exceptions=False)  # the lifespan already ran in `client`
    r = raw.post("/recognize", files={"rgb": ("g.png", png(GREY))})
    assert r.status_code == 500 and r.json() == {"detail": "internal error (RuntimeError)"}


def test_empty_api_key_means_none(tmp_path, posedesc_models):
    assert service_settings(tmp_path, posedesc_models, api_key="  ").api_key is None
    assert service_settings(tmp_path, posedesc_models, api_key="k").api_key.get_secret_value() == "k"


def test_a_changed_model_gets_its_templates_made_again(tmp_path, posedesc_models, l_shape):
    onnx = pytest.importorskip("onnx")
    models = tmp_path / "models"
    shutil.copytree(posedesc_models, models)
    with TestClient(create_app(service_settings(tmp_path / "data", models))) as c:
        wait_ready(c)
        oid = register(c, l_shape, "L")["object_id"]
    model = onnx.load(str(models / "posedesc-rgb.onnx"))  # "retrained": a new file, a new fingerprint
    model.metadata_props.add(key="note", value="retrained")
    onnx.save(model, str(models / "posedesc-rgb.onnx"))
    with TestClient(create_app(service_settings(tmp_path / "data", models))) as c:
        ready = wait_ready(c)
        want = {m: expected_templates(models, m) for m in ("rgb", "depth", "rgbd")}
        assert ready["templates"] == want and ready["detail"] is None
        assert c.get(f"/objects/{oid}").json()["templates"]["rgb"] == want["rgb"]


def test_a_camera_jpeg_with_two_pictures_is_accepted(client):
    """Phones save some photos as MPO: a JPEG followed by more pictures; the first one is used."""
    buf = io.BytesIO()
    first = Image.fromarray(GREY)
    first.save(buf, format="MPO", save_all=True, append_images=[Image.fromarray(255 - GREY)])
    r = client.post("/recognize", files={"rgb": ("photo.jpg", buf.getvalue())})
    assert r.status_code == 200, r.text


def test_only_png_and_jpeg_are_parsed(client):
    buf = io.BytesIO()
    Image.fromarray(GREY).save(buf, format="TIFF")
    r = client.post("/recognize", files={"rgb": ("a.tiff", buf.getvalue())})
    assert r.status_code == 422 and r.json() == {"detail": "rgb: a TIFF, not a PNG or JPEG"}
