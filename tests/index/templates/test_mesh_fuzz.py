"""Fuzzing the mesh loader: valid files of every format, then bytes flipped, cut, repeated, numbers made
absurd. `load_mesh` either returns a usable mesh or raises MeshError (a 422 in the service), never any
other exception (a 500). How long a case takes is a figure of `posedesc bench --only guards` (the same
damage, drawn there from a seeded generator). (schemathesis cannot reach this: it names uploads after
their content's signature, and mesh formats have none it knows.)"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from benchmarks.serving.hostile import ABSURD, DAMAGE_KINDS, Damage, damage, glb_index_outside, valid_mesh
from index.templates.mesh import MESH_FORMATS, MeshError, load_mesh

FORMATS = [f for f in MESH_FORMATS if f != "gltf"]  # glTF's JSON points at buffers: as GLB, in one file


VALID = {fmt: valid_mesh(fmt) for fmt in FORMATS}

changes = st.builds(
    Damage,
    kind=st.sampled_from(DAMAGE_KINDS),
    at=st.integers(0, 1 << 20),
    size=st.integers(1, 64),
    times=st.integers(2, 50),
    value=st.one_of(st.sampled_from(ABSURD), st.binary(min_size=1, max_size=16)),
)


@st.composite
def damaged(draw: st.DrawFn) -> tuple[str, bytes]:
    fmt = draw(st.sampled_from(FORMATS))
    return fmt, damage(VALID[fmt], draw(st.lists(changes, min_size=1, max_size=4)))


@given(damaged())
@example(("glb", glb_index_outside(VALID["glb"])))  # found by this test
@example(("obj", b"v 1\nv 2\nv 3\nf 1 2 3\n"))  # vertices of one coordinate: found by this test
@settings(max_examples=300, deadline=None, database=None, suppress_health_check=list(HealthCheck))
def test_a_damaged_mesh_loads_or_is_refused_with_mesh_error(case):
    fmt, data = case
    try:
        mesh = load_mesh(data, file_type=fmt, max_faces=200_000, max_input_faces=500_000)
    except MeshError as e:
        assert "\n" not in str(e)
    else:
        assert len(mesh.faces) > 0 and np.isfinite(mesh.vertices).all()
        assert mesh.faces.max() < len(mesh.vertices)
