"""Helpers of the service tests (imported by path): settings for a temporary data dir, frames of a test
mesh, PNG bytes, registration that follows a 202 job, `posedesc serve` as a subprocess on a loopback port."""

from __future__ import annotations

import io
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import httpx
import numpy as np
import pytest
import trimesh
from PIL import Image

from index.geometry.pose import View, view_to_pose

ROOT = Path(__file__).resolve().parents[2]

# Kinect-like intrinsics (LineMOD's), 640 x 480.
K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def coloured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(
        mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1))
    )
    return mesh


def make_t_shape() -> trimesh.Trimesh:
    """A second asymmetric object, other colours and shape than the L of tests/conftest.py."""
    a = coloured(trimesh.creation.box(extents=[40, 40, 140]), (230, 200, 30))
    b = coloured(trimesh.creation.box(extents=[110, 25, 25]), (30, 200, 220))
    b.apply_translation([30, 0, 55])
    c = coloured(trimesh.creation.icosphere(radius=22), (220, 60, 200))
    c.apply_translation([0, 35, -40])
    m = trimesh.util.concatenate([a, b, c])
    m.apply_translation(-m.bounding_box.centroid)
    return m


def ply_bytes(mesh: trimesh.Trimesh) -> bytes:
    return mesh.export(file_type="ply")


def png(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def depth_png(depth_mm: np.ndarray) -> bytes:
    return png(np.round(depth_mm).astype(np.uint16))


def patch_files() -> dict[str, dict[str, tuple[str, bytes]]]:
    """Per model, the files of a plain patch (grey; 400 mm flat): with k = 100 the reliability tests get
    every template of their small stores back, so an answer shows exactly which objects it saw."""
    rgb = ("p.png", png(np.full((64, 64, 3), 120, np.uint8)))
    depth = ("d.png", depth_png(np.full((64, 64), 400.0)))
    return {"rgb": {"rgb": rgb}, "depth": {"depth": depth}, "rgbd": {"rgb": rgb, "depth": depth}}


def frame(renderer, mesh: trimesh.Trimesh, view: View, uv: tuple[float, float], wall_mm: float | None = None):
    """rgb, depth of `mesh` seen from `view` with its origin at pixel `uv`, optionally before a black wall."""
    ray = np.linalg.inv(K) @ np.array([uv[0], uv[1], 1.0])
    R, t = view_to_pose(view, ray=ray)
    scene = [(mesh, R, t)]
    if wall_mm:
        wall = coloured(trimesh.creation.box(extents=[8000, 8000, 10]), (0, 0, 0))
        scene.append((wall, np.eye(3), np.array([0.0, 0.0, wall_mm])))
    return renderer.render_frame(scene, K, W, H)


def frame_fields(uv: tuple[float, float], **extra) -> dict[str, str]:
    fields = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "u": uv[0], "v": uv[1], **extra}
    return {k: str(v) for k, v in fields.items()}


def service_settings(data_dir: Path, models: Path, **kw):
    from service.settings import Settings

    base = {"demo_objects": False, "level": 2, "sync_seconds": 60.0}
    return Settings(data_dir=data_dir, models_dir=models, **{**base, **kw})


def wait_ready(client, timeout: float = 120.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        r = client.get("/readyz")
        if r.status_code == 200:
            return r.json()
        time.sleep(0.1)
    raise AssertionError(f"not ready after {timeout} s: {r.json()}")


def register(client, mesh: trimesh.Trimesh, name: str, headers=None, timeout: float = 120.0, **data) -> dict:
    """POST /objects, following the job when the answer is 202; returns the created object."""
    r = client.post(
        "/objects",
        files={"mesh": (f"{name}.ply", ply_bytes(mesh))},
        data={"name": name, **data},
        headers=headers,
    )
    return created(client, r, timeout)


def created(client, r, timeout: float = 120.0) -> dict:
    """The object a POST /objects answer made: at once (201), or once its job is done (202)."""
    if r.status_code == 201:
        return r.json()
    assert r.status_code == 202, r.text
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        job = client.get(f"/jobs/{r.json()['job_id']}").json()
        if job["status"] != "running":
            assert job["status"] == "done", job
            return job["result"]
        time.sleep(0.1)
    raise AssertionError("registration did not finish")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve_command(
    port: int,
    data_dir: Path,
    models: Path,
    host: str = "127.0.0.1",
    log_level: str = "warning",
    args: Sequence[str] = (),
) -> list[str]:
    cmd = [sys.executable, "-m", "posedesc.cli", "serve", "--host", host, "--port", str(port)]
    return cmd + ["--data-dir", str(data_dir), "--models", str(models), "--log-level", log_level, *args]


class Server:
    """`posedesc serve` in a subprocess on a free port, reached on loopback (listening there unless `host`
    says otherwise); `env` adds POSEDESC_* settings, `args` command-line options."""

    def __init__(
        self,
        data_dir: Path,
        models: Path,
        env: dict[str, str] | None = None,
        host: str = "127.0.0.1",
        log_level: str = "warning",
        args: Sequence[str] = (),
    ):
        self.models = models
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        env = {
            **os.environ,
            "POSEDESC_DEMO_OBJECTS": "false",
            "POSEDESC_LEVEL": "2",
            "POSEDESC_SYNC_SECONDS": "30",
            **(env or {}),
        }
        cmd = serve_command(self.port, data_dir, models, host, log_level, args)
        self.log = data_dir.parent / f"server-{self.port}.log"
        with open(self.log, "wb") as out:  # the child keeps its own copy of the descriptor
            self.proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=out, stderr=subprocess.STDOUT)

    def wait_ready(self, timeout: float = 120.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                pytest.fail(f"server exited with {self.proc.returncode}:\n{self.log.read_text()[-3000:]}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        pytest.fail(f"server not ready:\n{self.log.read_text()[-3000:]}")

    def stop(self) -> int:
        """SIGTERM: uvicorn shuts down gracefully (the lifespan closes the store); the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=60)

    def kill(self) -> None:
        """SIGKILL: no shutdown at all, as in a crash or the OOM killer."""
        self.proc.kill()
        self.proc.wait(timeout=60)

    def memory_mb(self) -> tuple[float, float]:
        """The server's resident memory now and at its peak (VmRSS, VmHWM), MB."""
        fields = dict(
            line.split(":", 1) for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines()
        )
        return tuple(int(fields[k].split()[0]) / 1024 for k in ("VmRSS", "VmHWM"))  # type: ignore[return-value]

    def __enter__(self) -> Server:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=60)


def expected_templates(models: Path, modality: str, viewpoints: int = 71) -> int:
    """Templates an object without symmetry gets from `models`' model of `modality` at the tests' level
    (2: 71 viewpoints): times its in-plane variants when its metadata says it was trained with roll."""
    from index.features.embed import Embedder

    step = Embedder(models / f"posedesc-{modality}.onnx").info.inplane_step
    return viewpoints * (int(round(360.0 / step)) if step > 0 else 1)


def calibrated(models: Path, folder: Path, modality: str, calibrations: dict):
    """The test `modality` model of `models`, copied into `folder` with `calibrations` (score kind ->
    `service.rejection.Calibration`) as its open-set metadata, as `scripts/calibrate_reject.py` writes it."""
    import json

    from evaluation.calibration import write_metadata
    from index.features.embed import Embedder
    from service.rejection import REJECT_KEY

    name = f"posedesc-{modality}.onnx"
    payload = json.dumps({kind: cal.to_json() for kind, cal in calibrations.items()})
    write_metadata(models / name, folder / name, {REJECT_KEY: payload})
    return Embedder(folder / name)
