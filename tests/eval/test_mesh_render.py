"""Ray-cast renders of meshes for scoring: how many rays a pixel, and where they go."""

import numpy as np
import pytest
import trimesh

from va_plugin.data.rigs import orbit_cameras
from va_plugin.errors import ConfigError
from va_plugin.eval.mesh_render import MAX_SUPERSAMPLE, UnlitMeshRenderer, check_supersample, render_on_background

RES = 24


def red_box():
    mesh = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    return UnlitMeshRenderer(mesh, lambda hits: np.tile(np.float32([1.0, 0.0, 0.0]), (len(hits.points), 1)))


def test_one_ray_a_pixel_goes_through_its_centre_and_more_rays_blend_the_edges():
    renderer = red_box()
    cameras = orbit_cameras([30.0], [20.0], resolution=RES, pixel_offset=0.5)
    t, _, _ = renderer.cast(*renderer.pixel_rays(cameras, 0, 0.0, 0.0))
    centre_hits = np.isfinite(t).reshape(RES, RES)
    one = renderer.render(cameras, 0, supersample=1)
    # one ray a pixel: the alpha is exactly whether the ray through the pixel centre meets the box
    assert set(np.unique(one[..., 3])) == {0.0, 1.0}
    np.testing.assert_array_equal(one[..., 3] == 1.0, centre_hits)
    two = renderer.render(cameras, 0, supersample=2)
    partial = (two[..., 3] > 0) & (two[..., 3] < 1)
    assert partial.sum() > RES  # the outline's pixels are fractions of 2x2 rays
    assert set(np.round(np.unique(two[..., 3]) * 4, 6)) <= {0.0, 1.0, 2.0, 3.0, 4.0}
    # on a white background a fractional pixel is a blend of red and white
    on_white = render_on_background(renderer, cameras, 0, (1.0, 1.0, 1.0), supersample=2)
    blend = on_white[partial]
    np.testing.assert_allclose(blend[:, 0], 1.0, atol=1e-6)
    np.testing.assert_allclose(blend[:, 1], 1.0 - two[..., 3][partial], atol=1e-6)


@pytest.mark.parametrize("value", [0, -1, MAX_SUPERSAMPLE + 1, 1.5, True, "2"])
def test_a_bad_number_of_rays_is_refused_with_the_options_name(value):
    with pytest.raises(ConfigError, match="--rays must be a whole number"):
        check_supersample(value, "--rays")


def test_good_numbers_of_rays_pass():
    assert [check_supersample(v) for v in (1, 2, MAX_SUPERSAMPLE, np.int64(3))] == [1, 2, MAX_SUPERSAMPLE, 3]


@pytest.mark.parametrize("batch", [1, RES * RES * 3, 1 << 20])
def test_supersampled_rays_cast_together_give_the_average_of_each_shift(monkeypatch, batch):
    # one shifted copy a cast, three a cast (a last group of one), or all nine in one cast
    import va_plugin.raycast as raycast

    monkeypatch.setattr(raycast, "CAST_BATCH", batch)
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    renderer = UnlitMeshRenderer(mesh, lambda hits: np.clip(hits.points + 0.5, 0.0, 1.0).astype(np.float32))
    cameras = orbit_cameras([30.0], [20.0], resolution=RES, pixel_offset=0.5)
    offsets = (np.arange(3) + 0.5) / 3 - 0.5
    rgb_sum, hits = np.zeros((RES * RES, 3)), np.zeros(RES * RES)
    for dy in offsets:  # the reference: one cast per shift
        for dx in offsets:
            t, faces, bary = renderer.cast(*renderer.pixel_rays(cameras, 0, dy, dx))
            hit = np.isfinite(t)
            rgb_sum[hit] += renderer.shade(faces[hit], bary[hit])
            hits += hit
    image = renderer.render(cameras, 0, supersample=3).reshape(-1, 4)
    np.testing.assert_allclose(image[:, 3], hits / 9, atol=1e-7)
    seen = hits > 0
    assert 0 < seen.sum() < RES * RES
    np.testing.assert_allclose(image[seen, :3], rgb_sum[seen] / hits[seen, None], atol=1e-6)
    assert np.all(image[~seen, :3] == 0)
