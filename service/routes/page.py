"""The web page at `/`: plain HTML, JavaScript and CSS shipped in `service/static/` (no build step, nothing
from a CDN), and the examples of `service/examples/` one click away. None of it is in the OpenAPI schema:
it is a client of the API, not a part of it.

Only files known when the module loads are served: a requested name is looked up in a dict, never joined
to a path, so no name (`..%2Fsettings.py`, an absolute path) can reach another file."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from service.errors import ApiError

STATIC = Path(__file__).resolve().parents[1] / "static"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

MEDIA_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".png": "image/png",
    ".ply": "application/octet-stream",
}

# The page runs only its own script and style, talks only to this server, and shows images it fetched
# (blob: URLs of the drawn answers and of the frames picked): an object's name with markup in it stays text.
PAGE_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; object-src 'none'; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Cache-Control": "no-cache",  # revalidated (ETag), so an upgraded service serves its own page
}


def _files(folder: Path, suffixes: set[str]) -> dict[str, Path]:
    """The files of `folder` that may be served, by name (none when the folder was not installed)."""
    if not folder.is_dir():
        return {}
    return {p.name: p for p in sorted(folder.iterdir()) if p.is_file() and p.suffix in suffixes}


STATIC_FILES = _files(STATIC, {".js", ".css"})
# the frame (colour, depth) and the mesh the README's examples use; not the script that made them
EXAMPLE_FILES = _files(EXAMPLES, {".png", ".ply"})

router = APIRouter(include_in_schema=False)


def _serve(files: dict[str, Path], name: str, what: str) -> FileResponse:
    path = files.get(name)
    if path is None:
        raise ApiError(404, f"no {what} {name!r}; there are: {', '.join(files) or 'none'}")
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], headers=PAGE_HEADERS)


@router.get("/")
def page() -> FileResponse:
    return FileResponse(STATIC / "index.html", media_type=MEDIA_TYPES[".html"], headers=PAGE_HEADERS)


@router.get("/static/{name}")
def static(name: str) -> FileResponse:
    return _serve(STATIC_FILES, name, "file")


@router.get("/examples/{name}")
def example(name: str) -> FileResponse:
    return _serve(EXAMPLE_FILES, name, "example")
