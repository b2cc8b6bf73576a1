"""`index.templates.mesh`, a user's mesh loaded: every format read in mm, units applied and implausible ones
refused with the units that would fit, bad meshes refused, heavy ones simplified with their colours."""

import numpy as np
import pytest
import trimesh
from PIL import Image

from index.templates.mesh import FORMATS_TEXT, MESH_FORMATS, MeshError, diameter, load_mesh


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


@pytest.mark.parametrize("units,scale", [("cm", 0.1), ("m", 0.001), ("inch", 1 / 25.4)])
def test_a_file_in_other_units_is_refused_in_mm_and_read_in_its_own(tmp_path, l_shape, units, scale):
    small = l_shape.copy()
    small.apply_scale(scale)
    path = export(small, tmp_path / "m.ply", "ply")
    for said in ("mm", None):  # given as mm, or not given
        with pytest.raises(MeshError, match=rf"too small \(20-2,000 mm register\).* in {units} it is "):
            load_mesh(path, units=said, check_size=True)
    assert diameter(load_mesh(path, units=units, check_size=True)) == pytest.approx(
        diameter(l_shape), rel=1e-3
    )
    load_mesh(path)  # unasked, the size is not checked (BOP meshes, stored meshes)


def test_a_mesh_in_mm_read_as_metres_is_too_large(tmp_path, l_shape):
    path = export(l_shape, tmp_path / "m.ply", "ply")
    with pytest.raises(MeshError, match="too large.*read in mm it is 1"):
        load_mesh(path, units="m", check_size=True)


def test_gltf_must_be_self_contained(l_shape):
    embedded = l_shape.export(file_type="gltf", embed_buffers=True)["model.gltf"]
    assert len(load_mesh(embedded, file_type="gltf").faces) == len(l_shape.faces)
    separate = l_shape.export(file_type="gltf")
    assert len(separate) > 1  # the JSON and its buffer files
    with pytest.raises(MeshError, match="separate file: send a GLB, or a glTF with its buffers and images"):
        load_mesh(separate["model.gltf"], file_type="gltf")


def test_the_formats_text_names_every_format():
    assert all(f in FORMATS_TEXT.lower() for f in MESH_FORMATS)
    with pytest.raises(MeshError) as e:
        load_mesh(b"x", file_type="docx")
    assert FORMATS_TEXT in str(e.value)


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


def test_face_colours_are_kept_per_face_and_render(renderer):
    """A mesh coloured per face (a PLY's face colours): each face keeps its colour at its
    corners, a vertex split only where faces of other colours meet, and it renders (the renderer refused
    face colours: a registration's 500)."""
    from index.geometry.pose import View

    box = trimesh.creation.box(extents=[60, 60, 60])  # 12 faces, 8 corners
    sides = np.array([[220, 40, 40, 255], [40, 200, 60, 255], [40, 60, 220, 255]], np.uint8)
    box.visual = trimesh.visual.ColorVisuals(box, face_colors=np.repeat(sides, 4, axis=0))
    m = load_mesh(box.export(file_type="ply"), file_type="ply")
    assert m.visual.kind == "vertex" and len(m.faces) == 12
    corners = m.visual.vertex_colors[m.faces]  # (12, 3, 4)
    assert np.array_equal(corners, np.repeat(np.repeat(sides, 4, axis=0)[:, None], 3, axis=1))
    assert len(m.vertices) < 36  # faces of one colour share their corners
    one = trimesh.creation.box(extents=[60, 60, 60])
    one.visual = trimesh.visual.ColorVisuals(one, face_colors=np.tile(sides[0], (12, 1)))
    assert len(load_mesh(one.export(file_type="ply"), file_type="ply").vertices) == 8
    shots = renderer.render_upright(m, [View(azimuth=30.0, elevation=40.0, inplane=0.0, distance=400.0)])
    seen = shots.rgb[0].reshape(-1, 3)
    seen = seen[seen.sum(axis=1) > 0]  # the object's pixels, not the black background
    dominant = np.bincount(seen.argmax(axis=1), minlength=3) / len(seen)
    assert (dominant > 0.1).sum() >= 2  # sides of two colours in view at least, each its own colour


def test_a_mesh_that_simplifies_to_nothing_is_refused():
    copies = b"v 0 0 0\nv 100 0 0\nv 0 100 0\n" + b"f 1 2 3\n" * 1000  # one triangle, a thousand times
    with pytest.raises(MeshError, match="left none"):
        load_mesh(copies, file_type="obj", max_faces=100)


def test_the_diameter_is_measured_again_when_the_mesh_changes(l_shape):
    mesh = l_shape.copy()
    size = diameter(mesh)
    assert diameter(mesh) == size  # kept for the same vertices and faces
    mesh.apply_scale(2.0)
    assert diameter(mesh) == pytest.approx(2 * size)
    other = l_shape.copy()  # another mesh of the same shape: its own
    assert diameter(other) == size


def test_meshes_simplified_at_once_in_threads_are_each_their_own():
    """The service simplifies meshes on several threads at once (a registration, the pose fit's warm-up, a
    detection's masks); the decimation library keeps the mesh it works on in process-wide memory, loaded,
    decimated and read back in three calls: each thread must get its own mesh's result."""
    from concurrent.futures import ThreadPoolExecutor

    from index.templates.mesh import simplify

    meshes = [trimesh.creation.icosphere(subdivisions=5, radius=50.0 + 10 * i) for i in range(4)]
    meshes += [trimesh.creation.cylinder(radius=30.0, height=80.0 + i, sections=1000) for i in range(4)]
    alone = [simplify(m, 1500) for m in meshes]
    with ThreadPoolExecutor(4) as pool:
        for _ in range(3):
            together = list(pool.map(lambda m: simplify(m, 1500), meshes))
            for a, b in zip(alone, together, strict=True):
                assert np.array_equal(a.faces, b.faces) and np.allclose(a.vertices, b.vertices)


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian"])
def test_a_ply_cut_short_is_said_to_be_cut_short(tmp_path, l_shape, encoding):
    """Wherever a PLY is cut (in its header, between two properties, in its body), the refusal says that
    it is cut short, never what the parser tripped on (`KeyError: 'y'`) nor "no faces"."""
    whole = trimesh.exchange.ply.export_ply(l_shape, encoding="ascii" if encoding == "ascii" else "binary")
    end = whole.index(b"end_header")
    cuts = [40, whole.index(b"property float y") + 5, end - 3, end + 11, end + 40, len(whole) // 2]
    for cut in cuts:
        (tmp_path / "cut.ply").write_bytes(whole[:cut])
        with pytest.raises(MeshError) as e:
            load_mesh(tmp_path / "cut.ply")
        said = str(e.value)
        assert "cut short" in said or "unexpected length" in said, (cut, said)
        assert "KeyError" not in said and "IndexError" not in said
    (tmp_path / "whole.ply").write_bytes(whole)
    assert len(load_mesh(tmp_path / "whole.ply").faces) == len(l_shape.faces)


@pytest.mark.parametrize(
    ("image", "mode", "pixel"),
    [
        (
            lambda: Image.fromarray(np.full((4, 4), 40000, np.uint16)),
            "RGB",
            [155] * 3,
        ),
        (lambda: Image.fromarray(np.full((4, 4), 0.5, np.float32)), "RGB", [127] * 3),
        (lambda: Image.new("LA", (4, 4), (200, 90)), "RGBA", [200, 200, 200, 90]),
        (lambda: Image.new("1", (4, 4), 1), "RGB", [255] * 3),
    ],
)
def test_a_texture_of_any_mode_is_made_8_bit_rgb_as_the_renderer_takes_it(image, mode, pixel):
    """A 16-bit or float grey is scaled from its range (not clipped to white); grey with alpha keeps its alpha."""
    from index.templates.mesh import _eight_bit

    out = _eight_bit(image())
    assert out.mode == mode and np.asarray(out)[0, 0].tolist() == pixel
