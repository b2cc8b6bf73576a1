"""A client of the posedesc service that needs nothing beyond Python's standard library (urllib, json), so
it runs wherever `make serve` does, or on any machine with Python 3.10+: copy this one file.

    from posedesc.client import Client

    api = Client("http://127.0.0.1:8000")  # api_key="..." when the service has one
    answer = api.recognize("frame.png", "depth.png", fx=572.4, fy=573.6, cx=325.3, cy=242.0, u=380, v=250)
    print(answer["best"])  # None when nothing registered is close enough; answer["reason"] says why
    obj = api.register("part.ply", name="part")  # follows the registration's job until it is done

Every method returns the service's JSON; an error answer (4xx, 5xx) raises `ApiError` with its status
and the service's one-line message."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

#: seconds between two looks at a running registration job
POLL_SECONDS = 0.5

Upload = str | Path | bytes


class ApiError(Exception):
    """An error answer: its HTTP status and the service's message (`detail`), or what went wrong on the
    way there (status 0: the service could not be reached)."""

    def __init__(self, status: int, message: str):
        super().__init__(f"{status}: {message}" if status else message)
        self.status, self.message = status, message


def _file(value: Upload, default_name: str) -> tuple[str, bytes]:
    """(file name, content) of a path or of bytes."""
    if isinstance(value, bytes):
        return default_name, value
    path = Path(value)
    return path.name, path.read_bytes()


def multipart(fields: Mapping[str, object], files: Mapping[str, tuple[str, bytes]]) -> tuple[bytes, str]:
    """A multipart/form-data body (RFC 7578) and its content type: text fields, then files."""
    boundary = f"posedesc-{uuid.uuid4().hex}"
    parts: list[bytes] = []
    for name, value in fields.items():
        head = f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"\r\n\r\n'
        parts.append(head.encode() + str(value).encode() + b"\r\n")
    for name, (filename, content) in files.items():
        safe = filename.replace('"', "_").replace("\r", "_").replace("\n", "_")
        head = (
            f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{safe}"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n"
        )
        parts.append(head.encode() + content + b"\r\n")
    parts.append(f"--{boundary}--\r\n".encode())
    return b"".join(parts), f"multipart/form-data; boundary={boundary}"


class Client:
    """The service at `base_url`. `api_key`: sent as X-API-Key (writes need it when the service has one);
    `timeout`: seconds per request."""

    def __init__(
        self, base_url: str = "http://127.0.0.1:8000", api_key: str | None = None, timeout: float = 60
    ):
        self.base_url, self.api_key, self.timeout = base_url.rstrip("/"), api_key, timeout

    def _call(
        self,
        method: str,
        path: str,
        body: bytes | None = None,
        content_type: str | None = None,
        accept: tuple[int, ...] = (),
    ) -> Any:
        """The decoded JSON answer (None for an empty one, as 204); ApiError for an error answer, except
        those of the `accept` statuses, whose JSON is returned."""
        headers = {"Accept": "application/json"}
        if content_type:
            headers["Content-Type"] = content_type
        if self.api_key is not None:
            headers["X-API-Key"] = self.api_key
        req = urllib.request.Request(self.base_url + path, data=body, headers=headers, method=method)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as r:
                data = r.read()
        except urllib.error.HTTPError as e:
            raw = e.read()
            if e.code in accept:
                return json.loads(raw)
            try:
                message = json.loads(raw)["detail"]
            except (ValueError, KeyError, TypeError):
                message = raw.decode(errors="replace") or e.reason
            raise ApiError(e.code, str(message)) from None
        except (urllib.error.URLError, OSError) as e:
            reason = getattr(e, "reason", e)
            raise ApiError(0, f"cannot reach {self.base_url}: {reason}") from None
        return json.loads(data) if data else None

    def _post_form(
        self, path: str, fields: Mapping[str, object], files: Mapping[str, tuple[str, bytes]]
    ) -> Any:
        body, content_type = multipart({k: v for k, v in fields.items() if v is not None}, files)
        return self._call("POST", path, body, content_type)

    def recognize(
        self,
        rgb: Upload | None = None,
        depth: Upload | None = None,
        *,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        u: float | None = None,
        v: float | None = None,
        distance_mm: float | None = None,
        depth_scale: float | None = None,
        k: int | None = None,
        **fields: object,
    ) -> dict:
        """`POST /recognize`: a colour and/or depth image (a path or the file's bytes): a patch centred on
        the object, or a full frame with `fx fy cx cy` and the object's centre `u v` (`distance_mm` for a
        colour-only frame), or a full frame without `u v`: every registered object found in it (the
        answer's `detections`). `fields`: any other form field (`max_detections`, `min_confidence`, ...),
        as the service documents it."""
        files = {}
        if rgb is not None:
            files["rgb"] = _file(rgb, "rgb.png")
        if depth is not None:
            files["depth"] = _file(depth, "depth.png")
        given = dict(
            fx=fx, fy=fy, cx=cx, cy=cy, u=u, v=v, distance_mm=distance_mm, depth_scale=depth_scale, k=k
        )
        return self._post_form("/recognize", {**given, **fields}, files)

    def register(
        self,
        mesh: Upload,
        name: str | None = None,
        *,
        units: str | None = None,
        symmetry: str | None = None,
        wait: bool = True,
        poll_seconds: float = POLL_SECONDS,
        filename: str | None = None,
        **fields: object,
    ) -> dict:
        """`POST /objects`: registers a mesh (a path, or bytes with `filename` saying its format: "part.ply")
        under `name` (default: the file's stem). Returns the created object; a registration that outlasts
        the request (202) is followed on `GET /jobs/{id}` until it is done, unless `wait=False`, which
        returns the job (`job_id`, `status`) at once. A failed job raises ApiError with its message."""
        if isinstance(mesh, bytes) and filename is None:
            raise ValueError("mesh given as bytes: say its format with filename='part.ply'")
        file_name, content = _file(mesh, filename or "mesh")
        file_name = filename or file_name
        name = name or Path(file_name).stem
        answer = self._post_form(
            "/objects",
            {"name": name, "units": units, "symmetry": symmetry, **fields},
            {"mesh": (file_name, content)},
        )
        if "job_id" not in answer or not wait:
            return answer
        while True:
            job = self.job(answer["job_id"])
            if job["status"] == "done":
                return job["result"]
            if job["status"] == "failed":
                raise ApiError(job.get("code") or 500, job.get("error") or "registration failed")
            time.sleep(poll_seconds)

    def job(self, job_id: str) -> dict:
        """`GET /jobs/{id}`: a registration's status, its progress, then its object."""
        return self._call("GET", f"/jobs/{job_id}")

    def objects(self) -> list:
        """`GET /objects`: every registered object (the demo objects have `"demo": true`)."""
        return self._call("GET", "/objects")

    def get(self, object_id: int) -> dict:
        """`GET /objects/{id}`."""
        return self._call("GET", f"/objects/{int(object_id)}")

    def delete(self, object_id: int) -> dict:
        """`DELETE /objects/{id}`: the object removed (as it was listed just before)."""
        removed = self.get(object_id)
        self._call("DELETE", f"/objects/{int(object_id)}")
        return removed

    def health(self) -> dict:
        """`GET /readyz`: `status` (ready; starting, or unavailable when its store does not answer: the
        service then answers 503, returned here too), models, objects, templates per model."""
        return self._call("GET", "/readyz", accept=(503,))
