"""Fuzzing: schemathesis makes requests from the OpenAPI schema and sends them to `posedesc serve` on a
loopback port; no answer may be a 5xx, and every answer (status, content type, body) must be one the
schema documents. Invalid data must be refused (4xx), never accepted."""

from __future__ import annotations

import io

import httpx
import numpy as np
import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st
from PIL import Image
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    negative_data_rejection,
    response_schema_conformance,
    status_code_conformance,
)
from service_helpers import Server, register

from service.main import app

# schemathesis against a real server, hundreds of requests: `make test`, not `make check`
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("no-5xx")]  # one server, on one worker

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    negative_data_rejection,
]


@st.composite
def images(draw: st.DrawFn) -> bytes:
    """Small PNG or JPEG images of any mode the service may get: colour, grey, 16-bit, palette, alpha."""
    w = draw(st.integers(8, 96))
    h = draw(st.one_of(st.just(w), st.integers(8, 96)))  # square (a patch) as often as not
    mode = draw(st.sampled_from(["RGB", "L", "RGBA", "I;16", "P", "1"]))
    fmt = draw(st.sampled_from(["PNG", "JPEG"])) if mode in ("RGB", "L") else "PNG"
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if mode == "I;16":  # depth in mm, with holes
        im = Image.fromarray(
            rng.integers(0, 3000, (h, w)).astype(np.uint16) * rng.integers(0, 2, (h, w), np.uint16)
        )
    else:
        im = Image.fromarray(rng.integers(0, 256, (h, w, 3), np.uint8)).convert(mode)
    buf = io.BytesIO()
    im.save(buf, format=fmt)
    return buf.getvalue()


# File fields get real images half of the time, so the fuzzing reaches decoding, cropping and search.
schemathesis.openapi.format("binary", st.one_of(images(), st.binary(max_size=256)))


@pytest.fixture(scope="module")
def server(tmp_path_factory, posedesc_models, l_shape):
    data_dir = tmp_path_factory.mktemp("fuzz") / "data"
    with Server(data_dir, posedesc_models, env={"POSEDESC_LEVEL": "1"}) as s:  # 16 templates an object
        s.wait_ready()
        with httpx.Client(base_url=s.url, timeout=60) as c:
            assert c.get("/openapi.json").json() == app.openapi()  # the schema below is the served one
            register(c, l_shape, "L")  # so that /recognize has matches to answer with
        yield s
        assert "Traceback" not in s.log.read_text()


# The schema the server serves at /openapi.json, made by the same code (it needs no lifespan); loaded at
# import so that every operation is a test of its own (the plugin's fixture-based loading does not work
# with pytest 9).
schema = schemathesis.openapi.from_dict(app.openapi())


@schema.parametrize()
@settings(
    max_examples=100,
    deadline=None,
    database=None,  # no .hypothesis/ folder in the working tree
    suppress_health_check=list(HealthCheck),
    phases=[Phase.explicit, Phase.generate],
)
def test_no_5xx_and_every_answer_in_the_schema(case, server):
    case.call_and_validate(base_url=server.url, checks=CHECKS)
