"""The Makefile's set-up recipes, as a fresh clone runs them: every variable they use is defined (a lost
definition once turned `$(PIP) -r $(LOCK)` into `-r`, which make runs as the command `r`, errors
ignored, and CI failed on a machine without a venv while every machine with one stayed green)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TARGETS = ("setup", "setup-serve", "lint", "test", "check", "serve", "bench", "lock")


@pytest.mark.parametrize("target", TARGETS)
def test_recipe_uses_only_defined_variables(target: str) -> None:
    # -n prints the recipes without running them, -B as if nothing were built yet (a fresh clone).
    run = subprocess.run(
        ["make", "-n", "-B", "--no-print-directory", "--warn-undefined-variables", target],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    assert "undefined variable" not in run.stderr, run.stderr


def test_setup_installs_from_the_locks() -> None:
    run = subprocess.run(
        ["make", "-n", "-B", "--no-print-directory", "setup"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    assert "pip install" in run.stdout and "-r requirements.lock" in run.stdout, run.stdout
    assert not any(line.startswith(("-r", "r ")) for line in run.stdout.splitlines()), run.stdout


def test_check_runs_the_tests_not_marked_slow_and_test_runs_them_all() -> None:
    def recipe(target: str) -> list[str]:
        run = subprocess.run(
            ["make", "-n", "-B", "--no-print-directory", *target.split()],
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        assert run.returncode == 0, run.stderr
        return [line.strip() for line in run.stdout.splitlines() if "pytest" in line]

    assert recipe("check") == ['.venv/bin/pytest -q -m "not slow" -n 2 --dist loadgroup']
    assert recipe("test") == [
        ".venv/bin/pytest -q --durations=25 -n 2 --dist loadgroup"
    ]  # every tier: nothing deselected
    assert recipe("test PARALLEL=") == [".venv/bin/pytest -q --durations=25"]  # one process, on request
    phony = next(line for line in (ROOT / "Makefile").read_text().splitlines() if line.startswith(".PHONY:"))
    assert "check" in phony.split()


def test_the_slow_marker_is_declared_and_deselects() -> None:
    """`-m "not slow"` leaves out a test marked slow (an undeclared marker would only warn)."""
    run = subprocess.run(
        [
            str(ROOT / ".venv/bin/pytest"),
            "--collect-only",
            "-q",
            "-m",
            "not slow",
            "tests/deploy/test_image.py",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert "no tests collected" in run.stdout and "deselected" in run.stdout, run.stdout
