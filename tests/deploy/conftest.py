"""podman for the image tests: this machine's settings, an offline Debian base image, the built image.

No Docker engine runs here and no registry is reachable, so the base is made with debootstrap from the
machine's own Debian mirror and imported once (`localhost/debian:bookworm`, kept between runs); the image
is built with podman's layer cache, so a second run rebuilds only what changed."""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
BASE_IMAGE = "localhost/debian:bookworm"
IMAGE = "localhost/posedesc:test"
# The machine's trust store: pip inside the build reaches PyPI through the same TLS path as pip here.
CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")


class Podman:
    """podman with this machine's settings: runc (crun refuses its hybrid cgroups), ulimits within its limits."""

    env = {**os.environ, "CONTAINERS_CONF": str(DEPLOY / "containers.conf")}

    def __call__(
        self, *args: str, check: bool = True, timeout: float = 600
    ) -> subprocess.CompletedProcess[str]:
        r = subprocess.run(["podman", *args], env=self.env, capture_output=True, text=True, timeout=timeout)
        if check and r.returncode:
            raise AssertionError(
                f"podman {' '.join(args)}: exit {r.returncode}\n{r.stdout[-3000:]}{r.stderr[-3000:]}"
            )
        return r

    def logs(self, container: str) -> str:
        r = self("logs", "--tail", "60", container, check=False)
        return r.stdout + r.stderr

    def wait_ready(self, url: str, container: str, timeout: float = 600) -> float:
        """Polls `url`/readyz until 200 and returns the seconds it took; fails early if the container stops."""
        start = time.monotonic()
        while time.monotonic() < start + timeout:
            try:
                if httpx.get(f"{url}/readyz", timeout=5).status_code == 200:
                    return time.monotonic() - start
            except httpx.HTTPError:
                pass
            if self("inspect", "-f", "{{.State.Running}}", container).stdout.strip() != "true":
                pytest.fail(f"{container} stopped before it was ready:\n{self.logs(container)}")
            time.sleep(1)
        pytest.fail(f"{container} not ready after {timeout:.0f} s:\n{self.logs(container)}")

    @staticmethod
    def free_port() -> int:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]


def debian_mirror() -> str:
    """The Debian mirror this machine's apt uses for bookworm (deb822 or one-line sources)."""
    files = [Path("/etc/apt/sources.list"), *sorted(Path("/etc/apt/sources.list.d").glob("*"))]
    for f in (f for f in files if f.is_file()):
        text = f.read_text()
        for stanza in re.split(r"\n\s*\n", text):
            fields = dict(
                (k.strip().lower(), v.split())
                for k, _, v in (line.partition(":") for line in stanza.splitlines())
                if not k.startswith("#") and v
            )
            if "deb" in fields.get("types", []) and "bookworm" in fields.get("suites", []):
                return fields["uris"][0]
        for line in text.splitlines():
            words = re.sub(r"\[.*?\]", "", line.split("#", 1)[0]).split()
            if len(words) >= 3 and words[0] == "deb" and words[2] == "bookworm":
                return words[1]
    return "http://deb.debian.org/debian"


@pytest.fixture(scope="session")
def podman() -> Podman:
    """Skips while the service is not written yet; podman itself comes with `make setup`."""
    if not (ROOT / "posedesc" / "commands" / "serve.py").is_file():
        pytest.skip("the service is not there yet (posedesc/commands/serve.py): nothing to serve")
    if shutil.which("podman") is None:
        message = "podman not installed: `make setup` installs it"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return Podman()


@pytest.fixture(scope="session")
def base_image(podman: Podman) -> str:
    """A bare Debian bookworm made offline from the machine's mirror (its sources point there too)."""
    if podman("image", "exists", BASE_IMAGE, check=False).returncode == 0:
        return BASE_IMAGE
    with tempfile.TemporaryDirectory(prefix="bookworm-") as tmp:
        root = Path(tmp) / "root"
        r = subprocess.run(
            ["debootstrap", "--variant=minbase", "bookworm", str(root), debian_mirror()],
            capture_output=True,
            text=True,
            timeout=1200,
        )
        assert r.returncode == 0, f"debootstrap failed:\n{r.stdout[-3000:]}{r.stderr[-3000:]}"
        tar = subprocess.Popen(["tar", "-C", str(root), "-c", "."], stdout=subprocess.PIPE)
        imp = subprocess.run(
            ["podman", "import", "-", BASE_IMAGE], stdin=tar.stdout, env=podman.env, capture_output=True
        )
        tar.stdout.close()
        assert tar.wait() == 0 and imp.returncode == 0, imp.stderr.decode()[-3000:]
    return BASE_IMAGE


@pytest.fixture(scope="session")
def image(podman: Podman, base_image: str) -> str:
    """deploy/Dockerfile built on the local base; docker format, which keeps the HEALTHCHECK."""
    secret = ["--secret", f"id=pip-ca,src={CA_BUNDLE}"] if CA_BUNDLE.is_file() else []
    podman(
        "build",
        "--format",
        "docker",
        "--layers",
        "--build-arg",
        f"BASE_IMAGE={base_image}",
        *secret,
        "-f",
        str(DEPLOY / "Dockerfile"),
        "-t",
        IMAGE,
        str(ROOT),
        timeout=1800,
    )
    return IMAGE
