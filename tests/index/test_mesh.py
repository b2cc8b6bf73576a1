import numpy as np
import pytest
import trimesh

from index.mesh import MeshError, diameter, load_mesh, scale_warning


def export(mesh: trimesh.Trimesh, path, fmt: str):
    data = mesh.export(file_type=fmt)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


@pytest.mark.parametrize("fmt", ["ply", "obj", "stl", "glb", "off"])
def test_formats_load_in_mm(tmp_path, l_shape, fmt):
    m = load_mesh(export(l_shape, tmp_path / f"m.{fmt}", fmt))
    assert len(m.faces) == len(l_shape.faces)
    assert diameter(m) == pytest.approx(diameter(l_shape), rel=1e-3)


def test_metres_are_scaled(tmp_path, l_shape):
    small = l_shape.copy()
    small.apply_scale(0.001)
    m = load_mesh(export(small, tmp_path / "m.ply", "ply"), units="m")
    assert diameter(m) == pytest.approx(diameter(l_shape), rel=1e-3)


def test_scale_warnings(l_shape):
    assert scale_warning(l_shape, 200) is None
    tiny = l_shape.copy()
    tiny.apply_scale(0.001)
    assert "units=m" in scale_warning(tiny, 200)
    huge = l_shape.copy()
    huge.apply_scale(1000)
    assert "metres" in scale_warning(huge, 200)


def test_bad_meshes_are_refused(tmp_path):
    (tmp_path / "a.ply").write_text("this is not a mesh")
    with pytest.raises(MeshError, match="not a readable"):
        load_mesh(tmp_path / "a.ply")
    with pytest.raises(MeshError, match="unsupported"):
        load_mesh(b"solid", file_type="docx")
    with pytest.raises(MeshError, match="no such file"):
        load_mesh(tmp_path / "missing.ply")
    empty = trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), int))
    with pytest.raises(MeshError, match="empty|no triangles"):
        load_mesh(empty.export(file_type="ply"), file_type="ply")
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]], process=False)
    with pytest.raises(MeshError, match="degenerate"):
        load_mesh(flat.export(file_type="ply"), file_type="ply")
    nan = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], faces=[[0, 1, 2]], process=False)
    with pytest.raises(MeshError, match="NaN"):
        load_mesh(nan.export(file_type="ply"), file_type="ply")


def test_heavy_mesh_is_simplified_with_colours(l_shape):
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=50)  # 81920 faces
    sphere.visual = trimesh.visual.ColorVisuals(
        sphere, vertex_colors=np.tile([10, 200, 30, 255], (len(sphere.vertices), 1))
    )
    m = load_mesh(sphere.export(file_type="ply"), file_type="ply", max_faces=5000)
    assert len(m.faces) <= 5000
    assert np.all(m.visual.vertex_colors[:, 1] == 200)


def test_a_mesh_that_simplifies_to_nothing_is_refused():
    copies = b"v 0 0 0\nv 100 0 0\nv 0 100 0\n" + b"f 1 2 3\n" * 1000  # one triangle, a thousand times
    with pytest.raises(MeshError, match="left none"):
        load_mesh(copies, file_type="obj", max_faces=100)
