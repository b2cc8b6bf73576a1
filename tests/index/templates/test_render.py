"""The renderer on meshes the tests make: geometry lands where the conventions say."""

import numpy as np
import pytest
import trimesh

from index.features.patches import PatchSpec, crop
from index.geometry.pose import View, view_to_pose
from index.templates.viewpoints import sphere_views

K = np.array([[572.4, 0, 325.3], [0, 573.6, 242.0], [0, 0, 1]])


def centroid(mask: np.ndarray) -> tuple[float, float]:
    ys, xs = np.nonzero(mask)
    return xs.mean(), ys.mean()


def test_origin_lands_at_patch_centre(renderer):
    box = trimesh.creation.box(extents=[60, 60, 60])
    t = renderer.render(box, [View(0, 90, 0, 400)])
    assert centroid(t.depth[0] > 0) == pytest.approx((31.5, 31.5), abs=1e-6)
    # the top face at 400 - 30 mm fills 60 mm = 60 * 64 / 200 px at 370 mm: 20.8 px / 370 * 400
    side = np.sqrt((t.depth[0] > 0).sum())
    assert side == pytest.approx(60 * 64 / 200 * 400 / 370, abs=1.5)
    assert np.median(t.depth[0][t.depth[0] > 0]) == pytest.approx(370, abs=1.0)


def test_all_301_templates(renderer, l_shape):
    t = renderer.render(l_shape, sphere_views(3))
    assert t.rgb.shape == (301, 64, 64, 3) and t.depth.shape == (301, 64, 64)
    filled = (t.depth > 0).mean(axis=(1, 2))
    assert filled.min() > 0.02 and filled.max() < 0.6
    # different viewpoints give different pictures
    assert np.abs(t.rgb[0].astype(int) - t.rgb[150].astype(int)).mean() > 5


def test_templates_without_colour_have_the_same_depth(renderer, l_shape):
    """A depth model's templates skip turning the colour: their depth is the same to the bit."""
    up = renderer.render_upright(l_shape, sphere_views(1, inplane=np.arange(0.0, 360.0, 30.0)))
    both, depth_only = up.templates(), up.templates(colour=False)
    assert np.array_equal(both.depth, depth_only.depth) and (both.depth > 0).any()
    assert not depth_only.rgb.any() and both.rgb.any()


def test_inplane_variant_equals_rolled_camera_render(renderer, l_shape):
    """A template turned in-plane is what a camera rolled by that angle sees."""
    v = View(60, 35, 30, 500)
    turned = renderer.render(l_shape, [v])
    R, t = view_to_pose(v)  # rolled camera, object on the optical axis
    rgb, depth = renderer.render_frame([(l_shape, R, t)], K, 640, 480)
    crgb, cdepth = crop(rgb, depth, K, (K[0, 2], K[1, 2]), 500, PatchSpec())
    a, b = turned.depth[0] > 0, cdepth > 0
    assert (a != b).mean() < 0.03
    assert np.abs(turned.depth[0][a & b] - cdepth[a & b]).mean() < 3


def test_off_axis_frame_crops_to_the_template(renderer, l_shape):
    """An object far off the optical axis, cropped with the true centre and in-plane, looks like its template."""
    v = View(200, 50, -35, 800)
    R, t = view_to_pose(v, ray=[0.3, 0.2, 1.0])
    rgb, depth = renderer.render_frame([(l_shape, R, t)], K, 640, 480)
    u, w = (K @ t)[:2] / t[2]
    crgb, cdepth = crop(rgb, depth, K, (u, w), np.linalg.norm(t), PatchSpec(), inplane=v.inplane)
    tmpl = renderer.render(l_shape, [View(200, 50, 0, 800)])
    a, b = tmpl.depth[0] > 0, cdepth > 0
    assert centroid(a) == pytest.approx(centroid(b), abs=1.0)  # nearest-neighbour resampling
    assert (a != b).mean() < 0.03
    assert np.abs(tmpl.depth[0][a & b] - cdepth[a & b]).mean() < 3
    assert np.abs(tmpl.rgb[0][a & b].astype(float) - crgb[a & b]).mean() < 12


@pytest.mark.parametrize("phi, a", [(70.0, 40.0), (-100.0, 60.0)])
def test_crop_undoes_a_roll_the_query_turns_sign(renderer, l_shape, phi, a):
    """crop(inplane=a) of an object rolled by phi shows it rolled phi - a: a template of in-plane θ found
    on the turn by a says the object is rolled θ + a (what `/recognize` answers with query turns)."""
    ray = [-0.2, 0.1, 1.0]
    R, t = view_to_pose(View(200, 50, phi, 700), ray=ray)
    rgb, depth = renderer.render_frame([(l_shape, R, t)], K, 640, 480)
    u, w = (K @ t)[:2] / t[2]
    _, cdepth = crop(rgb, depth, K, (u, w), np.linalg.norm(t), PatchSpec(), inplane=a)
    right = renderer.render(l_shape, [View(200, 50, phi - a, 700)]).depth[0] > 0
    wrong = renderer.render(l_shape, [View(200, 50, phi + a, 700)]).depth[0] > 0
    assert (right != (cdepth > 0)).mean() < 0.03
    assert (wrong != (cdepth > 0)).mean() > 0.1


def test_colours_come_through(renderer, l_shape):
    t = renderer.render(l_shape, [View(0, 90, 0, 400)])
    obj = t.rgb[0][t.depth[0] > 0].astype(int)
    reds = (obj[:, 0] > obj[:, 1] + 40) & (obj[:, 0] > obj[:, 2] + 40)
    greens = (obj[:, 1] > obj[:, 0] + 40) & (obj[:, 1] > obj[:, 2] + 40)
    assert reds.mean() > 0.15 and greens.mean() > 0.1


def test_renderer_refuses_other_threads(renderer, l_shape):
    import threading

    errors = []

    def other():
        try:
            renderer.render(l_shape, [View(0, 45)])
        except RuntimeError as e:
            errors.append(e)

    th = threading.Thread(target=other)
    th.start()
    th.join()
    assert errors and "thread" in str(errors[0])


def test_render_worker_owns_its_context(l_shape):
    from index.templates.render import RenderWorker

    w = RenderWorker()
    try:
        futs = [
            w.submit(lambda r, i=i: r.render(l_shape, [View(i * 30.0, 40)]).depth[0].sum()) for i in range(3)
        ]
        sums = [f.result(timeout=60) for f in futs]
        assert all(s > 0 for s in sums) and len(set(sums)) == 3
    finally:
        w.close()


def test_textured_mesh(renderer):
    from PIL import Image

    from index.templates.mesh import load_mesh

    box = trimesh.creation.box(extents=[100, 100, 100])
    uv = (box.vertices[:, :2] - box.vertices[:, :2].min(0)) / 100.0
    img = np.zeros((64, 64, 3), np.uint8)
    img[:, :32] = [255, 0, 0]
    img[:, 32:] = [0, 0, 255]
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(img))
    mesh = load_mesh(box.export(file_type="glb"), file_type="glb")
    t = renderer.render(mesh, [View(0, 90, 0, 400)])
    obj = t.rgb[0][t.depth[0] > 0].astype(int)
    red = (obj[:, 0] > 3 * obj[:, 2] + 10) & (obj[:, 1] < 5)
    blue = (obj[:, 2] > 3 * obj[:, 0] + 10) & (obj[:, 1] < 5)
    assert 0.3 < red.mean() < 0.7 and 0.3 < blue.mean() < 0.7
