"""The Docker image for real, under podman: serve, register a mesh, recognise it, restart, state kept.

The slowest tests of the suite: the first build takes minutes (apt, then the pinned wheels from PyPI);
after that podman's layer cache rebuilds only the source layers."""

from __future__ import annotations

import io
import os
import subprocess
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
import pytest
import trimesh
from PIL import Image

from index.geometry.pose import View

# the image and the session's Milvus: one worker under pytest-xdist (`make test`) makes them
pytestmark = [pytest.mark.container, pytest.mark.slow, pytest.mark.xdist_group("services")]
COMPOSE_FILE = Path(__file__).resolve().parents[2] / "deploy" / "docker-compose.yml"
CONTAINER_UID = 10001  # the Dockerfile's USER
HANG = 300.0  # seconds: only stops a wait that would never end, not a measure of speed
API_KEY = "test-key"  # the container listens on 0.0.0.0: writes need a key (or POSEDESC_ALLOW_OPEN_WRITES)


def png(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def register(url: str, mesh: trimesh.Trimesh, name: str, timeout: float = 600) -> str:
    """POST /objects; follows the job when the service answers 202."""
    files = {"mesh": ("object.ply", mesh.export(file_type="ply"), "application/octet-stream")}
    data = {"name": name, "units": "mm", "symmetry": "none"}
    r = httpx.post(f"{url}/objects", files=files, data=data, timeout=timeout)
    assert r.status_code == 401, r.text  # without the key
    r = httpx.post(f"{url}/objects", files=files, data=data, headers={"X-API-Key": API_KEY}, timeout=timeout)
    assert r.status_code in (201, 202), r.text
    if r.status_code == 201:
        return r.json()["object_id"]
    job = r.json()["job_id"]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = httpx.get(f"{url}/jobs/{job}", timeout=10).json()
        if status.get("object_id"):
            return status["object_id"]
        assert status.get("status") not in ("failed", "error"), status
        time.sleep(1)
    pytest.fail(f"registration job {job} not done after {timeout:.0f} s")


def run(podman, name: str, data_dir: str, port: int, image: str) -> None:
    # The timer of the HEALTHCHECK needs systemd, absent here; `podman healthcheck run` runs it by hand.
    podman(
        *f"run -d --name {name} --health-interval=disable -p 127.0.0.1:{port}:8000 -v {data_dir}:/data "
        f"-e POSEDESC_API_KEY={API_KEY} {image}".split()
    )


def test_image_serves_recognises_and_keeps_its_data(podman, image, tmp_path, l_shape, renderer) -> None:
    data = tmp_path / "data"
    data.mkdir()
    os.chown(data, CONTAINER_UID, CONTAINER_UID)  # the image runs as this uid, not root
    names = [f"posedesc-test-{uuid.uuid4().hex[:8]}" for _ in range(2)]
    try:
        port = podman.free_port()
        url = f"http://127.0.0.1:{port}"
        run(podman, names[0], str(data), port, image)
        podman.wait_ready(url, names[0])
        health = podman("healthcheck", "run", names[0], check=False)
        assert health.returncode == 0, health.stdout + health.stderr

        object_id = register(url, l_shape, "l-shape")
        patch = renderer.render(l_shape, [View(30.0, 40.0, 0.0, 600.0)]).rgb[0]
        r = httpx.post(
            f"{url}/recognize",
            files={"rgb": ("patch.png", png(patch), "image/png")},
            data={"k": "5"},
            timeout=60,
        )
        assert r.status_code == 200, r.text
        assert object_id in [m["object_id"] for m in r.json()["matches"]], r.json()

        # A new container on the same data dir: what was registered lives on the volume, not in the container.
        podman("rm", "-f", "-t", "20", names[0])
        port = podman.free_port()
        url = f"http://127.0.0.1:{port}"
        run(podman, names[1], str(data), port, image)
        podman.wait_ready(url, names[1])
        listed = httpx.get(f"{url}/objects", timeout=10).json()
        listed = listed.get("objects", listed) if isinstance(listed, dict) else listed
        assert object_id in [o["object_id"] for o in listed], (listed, podman.logs(names[1]))
    finally:
        for name in names:
            podman("rm", "-f", "-t", "5", name, check=False)


def test_compose_file_serves_on_a_named_volume(podman, image) -> None:
    """podman-compose (Debian's 1.0.3) runs deploy/docker-compose.yml with the image built above."""
    project = f"posedesc-test-{uuid.uuid4().hex[:8]}"
    port = podman.free_port()
    env = {**podman.env, "POSEDESC_IMAGE": image, "PUBLISH_ADDR": "127.0.0.1", "PUBLISH_PORT": str(port)}
    env["POSEDESC_API_KEY"] = ""  # the compose file's default: no key

    def compose(*args: str) -> subprocess.CompletedProcess[str]:
        cmd = ["podman-compose", "-p", project, "-f", str(COMPOSE_FILE), *args]
        return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)

    try:
        up = compose("up", "-d", "--no-build")
        assert up.returncode == 0, up.stdout + up.stderr
        container = podman(
            "ps", "-a", "-q", "--filter", f"label=io.podman.compose.project={project}"
        ).stdout.split()
        assert len(container) == 1, up.stdout + up.stderr
        podman.wait_ready(f"http://127.0.0.1:{port}", container[0])
        volume = podman("inspect", "-f", "{{range .Mounts}}{{.Type}} {{.Destination}}{{end}}", container[0])
        assert volume.stdout.split() == ["volume", "/data"]
        assert podman("exec", container[0], "test", "-w", "/data", check=False).returncode == 0, (
            "volume read-only"
        )
        assert httpx.get(f"http://127.0.0.1:{port}/objects", timeout=10).status_code == 200
        # no POSEDESC_API_KEY given: on the container's 0.0.0.0 the writes are refused
        assert httpx.delete(f"http://127.0.0.1:{port}/objects/1", timeout=10).status_code == 403
    finally:
        down = compose("down", "-v", "-t", "5")
        assert down.returncode == 0, down.stdout + down.stderr


def test_image_replicas_share_a_milvus_store(podman, image, milvus, tmp_path, l_shape) -> None:
    """Two containers of the image (pymilvus in it, from the serve lock) on the host's network, pointed at
    the session's real Milvus and one shared /data: registered through one, listed and deleted through
    the other. (The compose file's official Milvus images cannot be pulled here: no registry.)"""
    data = tmp_path / "shared"
    data.mkdir()
    os.chown(data, CONTAINER_UID, CONTAINER_UID)
    names = [f"posedesc-test-{uuid.uuid4().hex[:8]}" for _ in range(2)]
    prefix = f"img{uuid.uuid4().hex[:8]}"  # one store: both replicas name the same collections
    urls = []
    try:
        for name in names:
            port = podman.free_port()
            urls.append(f"http://127.0.0.1:{port}")
            podman(
                *f"run -d --name {name} --network host --health-interval=disable -v {data}:/data "
                f"-e POSEDESC_API_KEY={API_KEY} -e POSEDESC_STORE={milvus.uri} -e POSEDESC_STORE_PREFIX={prefix} "
                f"-e POSEDESC_DEMO_OBJECTS=false -e POSEDESC_LEVEL=1 "
                f"{image} serve --host 127.0.0.1 --port {port} --data-dir /data".split()
            )
        for url, name in zip(urls, names, strict=True):
            podman.wait_ready(url, name)
        object_id = register(urls[0], l_shape, "l-shape")
        deadline = time.monotonic() + HANG  # seen, however slowly (how soon: `posedesc bench --only milvus`)
        while object_id not in {o["object_id"] for o in httpx.get(f"{urls[1]}/objects", timeout=10).json()}:
            assert time.monotonic() < deadline, "never seen on the other replica"
            time.sleep(0.05)
        r = httpx.delete(f"{urls[1]}/objects/{object_id}", headers={"X-API-Key": API_KEY}, timeout=30)
        assert r.status_code == 204, r.text
        deadline = time.monotonic() + HANG
        while httpx.get(f"{urls[0]}/objects/{object_id}", timeout=10).status_code != 404:
            assert time.monotonic() < deadline, "deletion never seen on the first replica"
            time.sleep(0.05)
    finally:
        for name in names:
            podman("rm", "-f", name, check=False)
        from pymilvus import MilvusClient

        client = MilvusClient(milvus.uri)  # a later restart of the session's Milvus would reload them
        for c in client.list_collections():
            if c.startswith(prefix):
                client.drop_collection(c)
        client.close()
