"""Fixtures of the service tests; the helpers live in service_helpers.py."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from service_helpers import make_t_shape  # noqa: E402


@pytest.fixture(scope="session")
def t_shape():
    return make_t_shape()
