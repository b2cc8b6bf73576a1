"""The benchmark's many objects: image variants are distinct, and their descriptors made from transformed
network inputs equal those the service's own path makes from the transformed images."""

from __future__ import annotations

import numpy as np

from benchmarks.objects import VARIANTS, ObjectSet, variant
from index.features.embed import load_models
from index.geometry.pose import View


def tiny_set(shapes: int = 2) -> ObjectSet:
    rng = np.random.default_rng(0)
    views = [View(float(a), 30.0, 0.0, 400.0) for a in (0, 90, 200)]
    rgb = rng.integers(0, 255, (shapes, len(views), 64, 64, 3), dtype=np.uint8)
    depth = np.zeros((shapes, len(views), 64, 64), np.float32)
    depth[:, :, 10:50, 20:60] = rng.uniform(350, 420, (shapes, len(views), 40, 40))  # off-centre on purpose
    return ObjectSet(views, rgb, depth, 200.0, rgb[0, 0], depth[0, 0])


def test_variants_are_distinct_transforms():
    s = tiny_set()
    assert s.capacity == 2 * VARIANTS == 96
    firsts = {s.templates(j).rgb[0].tobytes() for j in range(0, s.capacity, 2)}  # every variant of shape 0
    assert len(firsts) == VARIANTS
    rgb, depth = variant(s.rgb[0], s.depth[0], 0)
    np.testing.assert_array_equal(rgb, s.rgb[0])
    assert np.array_equal(np.sort(s.templates(2 * 13).depth.ravel()), np.sort(s.depth[0].ravel()))


def test_embed_all_equals_the_service_path(posedesc_models):
    s = tiny_set()
    for modality, e in load_models(posedesc_models).items():
        fast = ObjectSet(s.views, s.rgb, s.depth, s.window_mm, s.query_rgb, s.query_depth)
        fast.embed_all(e, 40)
        for j in (0, 1, 5, 9, 18, 27, 39):  # identity, other shape, turns, mirrors, channel orders
            slow = s.template_set(e, j)  # index.templates.register.embed_templates on the variant's images
            got = fast.template_set(e, j)
            np.testing.assert_allclose(
                got.descriptors, slow.descriptors, rtol=1e-4, atol=1e-4, err_msg=modality
            )
            np.testing.assert_array_equal(got.poses, slow.poses)


def test_inplane_sets_are_what_registration_makes(posedesc_models, renderer):
    """Templates with in-plane variants: object j is shape j % m through a transform without a quarter
    turn; its descriptors are `index.templates.register.embed_templates` of the turned renders, in its order."""
    from benchmarks.objects import TURN_FREE_VARIANTS, inplane_template_sets, shapes
    from index.templates.register import embed_templates
    from index.templates.render import Templates
    from index.templates.viewpoints import inplane_steps, sphere_views

    models = load_models(posedesc_models)
    angles = inplane_steps(90.0, 180.0)  # -90, 0, 90, 180
    sets = inplane_template_sets(14, {"a": (models["rgb"], angles), "b": (models["depth"], [0.0])}, level=0)
    assert len(sets["a"]) == len(sets["b"]) == 14  # 2 shapes x 7 transforms
    views = sphere_views(0, angles)
    assert sets["a"][0].poses.shape == (6 * 4, 3) and sets["b"][0].poses.shape == (6, 3)
    np.testing.assert_array_equal(sets["b"][5].poses[:, 2], 0.0)
    first, second = shapes(2)
    for j, mesh, k in ((0, first, 0), (13, second, TURN_FREE_VARIANTS[6])):
        t = renderer.render(mesh, views)
        rgb, depth = variant(t.rgb, t.depth, k)
        expect = embed_templates(models["rgb"], {200.0: Templates(views, rgb, depth, 200.0)})
        np.testing.assert_allclose(sets["a"][j].descriptors, expect.descriptors, rtol=1e-4, atol=1e-4)
        np.testing.assert_array_equal(sets["a"][j].poses, expect.poses)
    assert not np.allclose(sets["a"][0].descriptors, sets["a"][2].descriptors)  # a mirror is another object
