"""Texture baking on hand-made cases: a cube whose colors are known everywhere, seen by known cameras."""

import numpy as np
import pytest
import trimesh
from texture_cases import RES, SIX_SIDES, TEXTURE, cube, cube_views, smooth_color, texel_truth

from va_plugin.data.rigs import orbit_cameras
from va_plugin.errors import VAError
from va_plugin.eval.mesh_render import UnlitMeshRenderer, render_on_background, textured_renderer
from va_plugin.export.atlas import simplify_for_texture
from va_plugin.export.texture import bake_texture, check_texture_size
from va_plugin.export.views import Views


def test_a_cube_seen_from_all_sides_bakes_back_its_colors():
    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, report = bake_texture(mesh, views, size=TEXTURE, fusion="robust")
    covered, points = texel_truth(textured)
    error = np.abs(textured.image[covered] - smooth_color(points)).mean(-1)
    # texels on the cube's edges lie on some view's silhouette edge: they are filled from their neighbours
    assert report.seen > 0.9 * report.covered
    assert np.median(error) < 0.005 and np.percentile(error, 95) < 0.03 and error.max() < 0.15
    # rendered back at a view it was not baked from, it matches a render of the true colors
    cameras = orbit_cameras([130.0], [35.0], resolution=RES, pixel_offset=0.5)
    truth = render_on_background(UnlitMeshRenderer(mesh, lambda h: smooth_color(h.points)), cameras, 0)
    baked = render_on_background(textured_renderer(textured), cameras, 0)
    assert np.abs(baked - truth).mean() < 0.005


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


def test_a_view_with_a_color_cast_is_levelled_before_fusion():
    """The cube seen from all sides, one view with a 15% red gain: with harmonisation the baked colors
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
        errors[harmonised] = np.abs(textured.image[covered] - smooth_color(points)).mean()
    clean, _ = bake_texture(mesh, views, size=TEXTURE, fusion="mean")
    covered, points = texel_truth(clean)
    baseline = np.abs(clean.image[covered] - smooth_color(points)).mean()
    assert errors[True] < baseline + 0.001 and errors[False] > 1.8 * errors[True]


def test_a_dense_mesh_is_simplified_before_the_unwrap_and_still_bakes_its_colors():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.35)  # 20480 faces
    simple = simplify_for_texture(sphere, 2000)
    views = cube_views(sphere, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, report = bake_texture(sphere, views, size=TEXTURE, max_faces=2000)
    assert len(textured.faces) == len(simple.faces) and "simplify" in report.seconds
    covered, points = texel_truth(textured)
    error = np.abs(textured.image[covered] - smooth_color(points)).mean(-1)
    assert np.median(error) < 0.01
    whole, _ = bake_texture(sphere, views, size=TEXTURE, max_faces=0)
    assert len(whole.faces) == len(sphere.faces)


def test_without_the_fill_unseen_texels_take_the_padding_and_seen_ones_stay():
    mesh = cube()
    views = cube_views(mesh, [0.0, 90.0], [20.0, 20.0])  # two sides and the top: the rest unseen
    filled, report = bake_texture(mesh, views, size=TEXTURE, fusion="mean")
    padded, report_padded = bake_texture(mesh, views, size=TEXTURE, fusion="mean", fill_unseen=False)
    assert report.seen == report_padded.seen < 0.8 * report.covered
    covered, _ = texel_truth(filled)
    seen = report.weight_maps.sum(0) > 0
    np.testing.assert_array_equal(filled.image[seen], padded.image[seen])
    assert np.abs(filled.image[covered & ~seen] - padded.image[covered & ~seen]).max() > 0.01
