"""The API's documentation: /docs and /redoc work offline (every asset served by the service itself), every
operation has a summary of its own, and the mesh formats are named the same in the API, its errors and the
README."""

from __future__ import annotations

import re

import pytest
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient
from service_helpers import ROOT, service_settings, wait_ready

from index.templates.mesh import FORMATS_TEXT
from service.main import create_app
from service.routes import health, jobs, objects, recognize

ASSET = re.compile(r"""(?:src|href)=["']([^"']+)["']""")
KIND = {".js": "javascript", ".css": "text/css", ".png": "image/png"}


@pytest.fixture(scope="module")
def client(tmp_path_factory, posedesc_models):
    with TestClient(create_app(service_settings(tmp_path_factory.mktemp("data"), posedesc_models))) as c:
        wait_ready(c)
        yield c


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_docs_pages_load_only_local_assets(client, page):
    r = client.get(page)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert "http://" not in r.text and "https://" not in r.text and "//cdn" not in r.text
    assets = ASSET.findall(r.text)
    assert any(a.endswith(".js") for a in assets), assets
    for url in assets:
        assert url.startswith("/") and not url.startswith("//"), url  # on this server
        got = client.get(url)
        assert got.status_code == 200, url
        assert KIND[url[url.rfind(".") :]] in got.headers["content-type"], (url, got.headers["content-type"])
        assert len(got.content) > 1000, url  # the real file, not a stub
    if page == "/docs":  # Swagger UI needs its bundle and its stylesheet
        assert {a.rsplit("/", 1)[-1] for a in assets} >= {"swagger-ui-bundle.js", "swagger-ui.css"}
        assert "url: '/openapi.json'" in r.text


def test_every_operation_has_its_own_summary(client):
    paths = client.get("/openapi.json").json()["paths"]
    assert len(paths) >= 7
    assert all(op.get("summary") for ops in paths.values() for op in ops.values())
    # ... written for it: FastAPI makes one up from the function's name ("Get Job") when a route gives none
    routes = [
        r for m in (recognize, objects, jobs, health) for r in m.router.routes if isinstance(r, APIRoute)
    ]
    assert {r.path for r in routes} == set(paths)
    assert [(r.path, r.methods) for r in routes if not r.summary] == []


def test_the_mesh_formats_are_named_the_same_everywhere(client):
    schema = client.get("/openapi.json").json()
    form = schema["components"]["schemas"]["Body_add_object_objects_post"]["properties"]
    assert FORMATS_TEXT in form["mesh"]["description"]
    for filename, where in (("x.docx", "unsupported mesh format"), ("noext", "needs an extension")):
        r = client.post("/objects", files={"mesh": (filename, b"hello")}, data={"name": "x"})
        assert r.status_code == 422 and where in r.json()["detail"] and FORMATS_TEXT in r.json()["detail"]
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert readme.count(FORMATS_TEXT) >= 2  # `posedesc render` and POST /objects
    assert "PLY/OBJ/STL/GLB" not in readme and "PLY, OBJ, STL or GLB" not in readme
