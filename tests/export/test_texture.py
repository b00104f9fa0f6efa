"""Texture baking on hand-made cases: a cube whose colours are known everywhere, seen by known cameras."""

import numpy as np
import pytest
import trimesh

from va_plugin.data.rigs import orbit_cameras
from va_plugin.errors import VAError
from va_plugin.eval.mesh_render import UnlitMeshRenderer, render_on_background, textured_renderer
from va_plugin.export.texture import (Views, apply_harmonisation, bake_texture, bilinear, check_texture_size,
                                      dilate, fuse, harmonise, simplify_for_texture, weighted_medoid,
                                      write_textured_mesh)

RES = 48
TEXTURE = 64


def smooth_colour(points: np.ndarray) -> np.ndarray:
    """A colour that varies slowly over the cube (so bilinear sampling errors stay small)."""
    return np.clip(0.5 + 0.8 * points[:, [0, 1, 2]] * np.array([1.0, -1.0, 1.0]), 0.0, 1.0).astype(np.float32)


def cube(size: float = 0.6) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(size, size, size))


def cube_views(mesh, azimuths, elevations, colour=smooth_colour):
    cameras = orbit_cameras(azimuths, elevations, resolution=RES, pixel_offset=0.5)
    renderer = UnlitMeshRenderer(mesh, lambda hits: colour(hits.points))
    images, masks = [], []
    for k in range(len(cameras)):
        rgba = renderer.render(cameras, k, supersample=3)
        images.append(rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:]))
        masks.append(rgba[..., 3] > 0.5)
    return Views(cameras, np.stack(images).astype(np.float32), np.stack(masks))


def texel_truth(textured):
    """Per covered texel: its known colour, from where it lies on the surface."""
    from va_plugin.export.texture import rasterize_uv

    face, bary = rasterize_uv(textured.uv, textured.faces, TEXTURE)
    covered = face >= 0
    corners = textured.faces[face[covered]]
    points = np.einsum("mk,mkc->mc", bary[covered], textured.vertices[corners])
    return covered, points


SIX_SIDES = dict(azimuths=[0, 90, 180, 270, 45, 135, 225, 315, 45, 225], elevations=[20] * 4 + [0] * 4 + [80, -80])


def test_a_cube_seen_from_all_sides_bakes_back_its_colours():
    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, report = bake_texture(mesh, views, size=TEXTURE, fusion="robust")
    covered, points = texel_truth(textured)
    error = np.abs(textured.image[covered] - smooth_colour(points)).mean(-1)
    # texels on the cube's edges lie on some view's silhouette edge: they are filled from their neighbours
    assert report.seen > 0.9 * report.covered
    assert np.median(error) < 0.005 and np.percentile(error, 95) < 0.03 and error.max() < 0.15
    # rendered back at a view it was not baked from, it matches a render of the true colours
    cameras = orbit_cameras([130.0], [35.0], resolution=RES, pixel_offset=0.5)
    truth = render_on_background(UnlitMeshRenderer(mesh, lambda h: smooth_colour(h.points)), cameras, 0)
    baked = render_on_background(textured_renderer(textured), cameras, 0)
    assert np.abs(baked - truth).mean() < 0.005


def test_an_occluded_texel_takes_no_colour_from_the_view_that_cannot_see_it():
    # a small box hides the middle of a big face from camera 0 only; the camera 0 colour there is red
    big = trimesh.creation.box(extents=(0.2, 1.0, 1.0))  # face at x = +0.1 faces camera 0 (on +x)
    blocker = trimesh.creation.box(extents=(0.1, 0.3, 0.3))
    blocker.apply_translation([0.6, 0, 0])
    mesh = trimesh.util.concatenate([big, blocker])
    cameras = orbit_cameras([0.0, 30.0], [0.0, 0.0], resolution=RES, pixel_offset=0.5)
    truth = UnlitMeshRenderer(mesh, lambda h: np.where(h.points[:, :1] > 0.4, [[1.0, 0.0, 0.0]],
                                                       [[0.2, 0.4, 0.9]]).astype(np.float32))
    images = []
    for k in range(2):
        rgba = truth.render(cameras, k, supersample=2)
        images.append(rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:]))
    views = Views(cameras, np.stack(images).astype(np.float32))
    textured, report = bake_texture(mesh, views, size=TEXTURE, fusion="mean")
    covered, points = texel_truth(textured)
    front = (np.abs(points[:, 0] - 0.1) < 1e-4) & (np.abs(points[:, 1]) < 0.06) & (np.abs(points[:, 2]) < 0.06)
    assert front.sum() > 3
    shares = report.weight_maps[:, covered][:, front]  # [views, texels]
    assert np.all(shares[0] == 0) and np.allclose(shares[1], 1.0)
    assert np.abs(textured.image[covered][front] - [0.2, 0.4, 0.9]).max() < 0.05


def test_a_wrong_view_is_outvoted_by_three_agreeing_ones():
    red, blue = [0.9, 0.1, 0.1], [0.1, 0.2, 0.9]
    colours = np.array([[red, red, red, blue]] * 200, np.float32)
    colours[:, :3] += np.random.default_rng(0).normal(0, 0.01, (200, 3, 3)).astype(np.float32)
    weights = np.tile(np.float32([0.5, 0.6, 0.7, 1.0]), (200, 1))  # the wrong view is the most head-on
    robust, share = fuse(colours, weights, "robust")
    mean, _ = fuse(colours, weights, "mean")
    assert np.abs(robust - red).max() < 0.05
    assert share[:, 3].max() < 0.02
    assert np.abs(mean - red).max() > 0.2  # a plain average would ghost


def test_agreeing_views_fuse_to_their_weighted_mean_either_way():
    rng = np.random.default_rng(1)
    colours = np.repeat(rng.uniform(0, 1, (100, 1, 3)), 4, 1).astype(np.float32)
    colours += rng.normal(0, 0.005, colours.shape).astype(np.float32)
    weights = rng.uniform(0.1, 1, (100, 4)).astype(np.float32)
    weights[:10, 2:] = 0
    robust, _ = fuse(colours, weights, "robust")
    mean, _ = fuse(colours, weights, "mean")
    assert np.abs(robust - mean).max() < 0.01


def test_medoid_picks_a_visible_colour():
    colours = np.float32([[[0, 0, 0], [1, 1, 1], [0.9, 0.9, 0.9]]])
    assert np.allclose(weighted_medoid(colours, np.float32([[1, 1, 0]])), [0, 0, 0])  # tie: first
    assert np.allclose(weighted_medoid(colours, np.float32([[1, 1, 1]])), [0.9, 0.9, 0.9])


def test_dilation_pads_charts_and_fills_the_rest():
    image = np.zeros((8, 8, 3), np.float32)
    filled = np.zeros((8, 8), bool)
    image[3, 3], filled[3, 3] = 0.7, True
    out = dilate(image, filled, iterations=2)
    assert np.allclose(out[1:6, 1:6], 0.7) and np.allclose(out, 0.7)


def test_bilinear_samples_pixel_centres_at_integers():
    image = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert np.allclose(bilinear(image, np.float32([0, 1.5, 9]), np.float32([0, 1, 2])), [0, 5.5, 11])


@pytest.mark.parametrize("size", [0, 15, 100, 1000, 16384])
def test_texture_sizes_must_be_sane_powers_of_two(size):
    with pytest.raises(VAError, match="power of two"):
        check_texture_size(size)


def test_bad_input_is_refused():
    mesh = cube()
    views = cube_views(mesh, [0.0], [20.0])
    with pytest.raises(VAError, match="no faces"):
        bake_texture(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int)), views, size=TEXTURE)
    far = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    far.apply_translation([0, 0, 5])  # behind / outside every camera
    with pytest.raises(VAError, match="view 0 sees no texel"):
        bake_texture(far, views, size=TEXTURE)


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_written_files_load_back_with_their_texture(tmp_path, suffix):
    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, _ = bake_texture(mesh, views, size=TEXTURE)
    written = write_textured_mesh(textured, tmp_path / f"cube{suffix}")
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(p.name for p in written)
    if suffix == ".obj":
        assert names == ["cube.mtl", "cube.obj", "cube.png"]
        assert "cube.png" in (tmp_path / "cube.mtl").read_text()
    loaded = trimesh.load(tmp_path / f"cube{suffix}", force="mesh")
    image = np.asarray(loaded.visual.material.to_simple().image if suffix == ".glb"
                       else loaded.visual.material.image).astype(np.float32)[..., :3] / 255
    assert image.shape == (TEXTURE, TEXTURE, 3)
    assert np.abs(image - textured.image).max() < 1.5 / 255
    assert len(loaded.faces) == len(textured.faces)
    # UVs survive the round trip (GLB stores v down; trimesh flips it back)
    assert np.abs(np.sort(loaded.visual.uv, 0) - np.sort(textured.uv, 0)).max() < 1e-4


def test_inconsistency_maps_weight_a_view_down_where_it_disagrees():
    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    _, plain = bake_texture(mesh, views, size=TEXTURE, fusion="mean")
    maps = np.zeros((len(views), RES // 2, RES // 2), np.float32)  # maps at half resolution, as va- runs make them
    maps[0] = 0.5  # view 0 disagrees with the shared object everywhere
    views.inconsistency = maps
    _, flagged = bake_texture(mesh, views, size=TEXTURE, fusion="mean")
    shared = (plain.weight_maps[0] > 0.05) & (plain.weight_maps[1:].sum(0) > 0.05)  # view 0 and others see
    assert shared.sum() > 50
    assert flagged.weight_maps[0][shared].max() < 1e-3
    # where view 0 is the only one to see a texel it still gives the colour (nothing better is at hand)
    alone = (plain.weight_maps[0] > 0) & (plain.weight_maps[1:].sum(0) == 0)
    assert alone.sum() > 10
    assert np.allclose(flagged.weight_maps[0][alone], 1.0)


def test_harmonise_recovers_each_views_gains_against_the_reference():
    """Three views of the same colours, view 1 brighter, view 2 darker with a blob of wrong colour on 10% of
    its points: the fitted per-view gains undo the casts (view 0 stays fixed), the blob does not bend them."""
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.1, 0.8, size=(2000, 3)).astype(np.float32)
    gain = np.array([[1.0, 1.0, 1.0], [1.12, 1.08, 0.92], [0.88, 0.92, 1.06]], np.float32)
    colours = truth[:, None] * gain[None]
    colours[:200, 2] = [0.9, 0.1, 0.9]  # a hallucinated blob in view 2
    weights = np.ones((2000, 3), np.float32)
    weights[1000:, 1] = 0.0  # view 1 sees half the points
    gains = harmonise(colours, weights)
    np.testing.assert_array_equal(gains[0], 1.0)
    np.testing.assert_allclose(gains[1:], 1.0 / gain[1:], rtol=0.005)
    fixed = apply_harmonisation(colours, weights, gains)
    assert np.abs(fixed[200:, 2] - truth[200:]).max() < 0.005 and np.abs(fixed[:1000, 1] - truth[:1000]).max() < 0.005
    np.testing.assert_array_equal(fixed[1000:, 1], colours[1000:, 1])  # where a view sees nothing, nothing changes
    colours[:, 1] *= 1.3  # beyond the trusted cast (MAX_GAIN): view 1 is left alone, view 2 still fitted
    gains = harmonise(colours, weights)
    np.testing.assert_array_equal(gains[1], 1.0)
    np.testing.assert_allclose(gains[2], 1.0 / gain[2], rtol=0.005)


def test_harmonise_leaves_views_without_overlap_alone():
    colours = np.random.default_rng(1).uniform(size=(100, 2, 3)).astype(np.float32)
    weights = np.zeros((100, 2), np.float32)
    weights[:50, 0] = weights[50:, 1] = 1.0
    np.testing.assert_array_equal(harmonise(colours, weights), 1.0)


def test_a_view_with_a_colour_cast_is_levelled_before_fusion():
    """The cube seen from all sides, one view with a 15% red gain: with harmonisation the baked colours
    stay as close to the truth as without the cast; without it, that view's texels come out red."""
    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    cast = views.images.copy()
    cast[1] = np.where(views.masks[1][..., None], np.clip(cast[1] * [1.15, 1.0, 1.0], 0, 1), cast[1])
    tinted = Views(views.cameras, cast, views.masks)
    errors = {}
    for harmonised in (True, False):
        textured, _ = bake_texture(mesh, tinted, size=TEXTURE, fusion="mean", harmonise_views=harmonised)
        covered, points = texel_truth(textured)
        errors[harmonised] = np.abs(textured.image[covered] - smooth_colour(points)).mean()
    clean, _ = bake_texture(mesh, views, size=TEXTURE, fusion="mean")
    covered, points = texel_truth(clean)
    baseline = np.abs(clean.image[covered] - smooth_colour(points)).mean()
    assert errors[True] < baseline + 0.001 and errors[False] > 1.8 * errors[True]


def test_a_dense_mesh_is_simplified_before_the_unwrap_and_still_bakes_its_colours():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.35)  # 20480 faces
    simple = simplify_for_texture(sphere, 2000)
    assert 1000 < len(simple.faces) <= 2000
    radius = np.linalg.norm(simple.vertices, axis=-1)
    assert np.abs(radius - 0.35).max() < 0.01  # the shape is kept
    assert simplify_for_texture(sphere, 0) is sphere and simplify_for_texture(sphere, 10**6) is sphere
    with pytest.raises(VAError, match="max-faces"):
        simplify_for_texture(sphere, 2)
    views = cube_views(sphere, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, report = bake_texture(sphere, views, size=TEXTURE, max_faces=2000)
    assert len(textured.faces) == len(simple.faces) and "simplify" in report.seconds
    covered, points = texel_truth(textured)
    error = np.abs(textured.image[covered] - smooth_colour(points)).mean(-1)
    assert np.median(error) < 0.01
    whole, _ = bake_texture(sphere, views, size=TEXTURE, max_faces=0)
    assert len(whole.faces) == len(sphere.faces)


def test_a_field_weight_blends_the_field_colour_in_where_views_see_the_surface_poorly():
    mesh = cube()
    views = cube_views(mesh, [0.0, 90.0], [20.0, 20.0])
    green = np.float32([0.1, 0.8, 0.2])
    field = lambda points, normals: np.tile(green, (len(points), 1))  # noqa: E731
    plain, plain_report = bake_texture(mesh, views, size=TEXTURE, fusion="mean", fallback=field)
    blended, report = bake_texture(mesh, views, size=TEXTURE, fusion="mean", fallback=field, field_weight=0.1,
                                   atlas=(plain.vertices, plain.faces, plain.uv))
    covered, _ = texel_truth(plain)
    seen = plain_report.weight_maps[:, covered].sum(0) > 0
    share = 1.0 - report.weight_maps[:, covered].sum(0)  # the field's share of each texel
    assert np.all(share[~seen] > 0.999)  # texels no view sees are the field's alone, as without a weight
    # a texel is the plain bake's colour and the field's, mixed by the field's share
    expected = (1.0 - share[seen, None]) * plain.image[covered][seen] + share[seen, None] * green
    assert np.abs(blended.image[covered][seen] - expected).max() < 1e-4
    # head-on texels keep their views' colour, grazing ones lean to the field's
    assert share[seen].min() < 0.1 and share[seen].max() > 0.4
    assert 0 < report.summary()["field_share"] < 1
    everywhere, _ = bake_texture(mesh, views, size=TEXTURE, fusion="robust", fallback=field, field_weight=1e6,
                                 atlas=(plain.vertices, plain.faces, plain.uv))
    assert np.abs(everywhere.image[covered] - green).max() < 1e-3


@pytest.mark.parametrize("weight", [-0.1, float("nan"), float("inf")])
def test_a_bad_field_weight_is_refused(weight):
    mesh = cube()
    views = cube_views(mesh, [0.0], [20.0])
    with pytest.raises(VAError, match="field's weight"):
        bake_texture(mesh, views, size=TEXTURE, fallback=lambda p, n: np.zeros_like(p), field_weight=weight)
    with pytest.raises(VAError, match="needs the field's colour"):
        bake_texture(mesh, views, size=TEXTURE, field_weight=0.1)


def test_anchored_on_the_field_a_lone_view_loses_a_blob_the_field_does_not_share():
    rng = np.random.default_rng(1)
    blue, red = np.float32([0.1, 0.2, 0.9]), np.float32([0.9, 0.1, 0.1])
    field = np.tile(blue, (200, 1)) + rng.normal(0, 0.01, (200, 3)).astype(np.float32)
    view = field + rng.normal(0, 0.01, (200, 3)).astype(np.float32)
    view[:20] = red  # a misprojected blob on a tenth of the points that only this view sees
    colours = np.stack([view, field], 1)
    weights = np.tile(np.float32([0.8, 0.1]), (200, 1))  # the view head-on, the field at its weight
    anchored, share = fuse(colours, weights, "robust", anchor=1)
    assert np.abs(anchored[:20] - blue).max() < 0.05 and share[:20, 0].max() < 0.05
    assert share[20:, 0].min() > 0.8  # elsewhere the view keeps its detail
    medoid, _ = fuse(colours, weights, "robust")  # judged against their medoid, the lone view wins
    assert np.abs(medoid[:20] - red).max() < 0.1
    mesh = cube()
    views = cube_views(mesh, [0.0], [20.0])
    with pytest.raises(VAError, match="anchoring"):
        bake_texture(mesh, views, size=TEXTURE, fallback=lambda p, n: np.zeros_like(p), field_anchor=True)
