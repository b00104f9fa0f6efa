"""Views seen from the surface: bilinear sampling, occlusion, inconsistency maps."""

import math

import numpy as np
import trimesh
from texture_cases import RES, SIX_SIDES, TEXTURE, cube, cube_views, texel_truth

from va_plugin.data.rigs import orbit_cameras
from va_plugin.eval.mesh_render import UnlitMeshRenderer
from va_plugin.export.texture import bake_texture
from va_plugin.export.views import Views, bilinear


def test_bilinear_samples_pixel_centres_at_integers():
    image = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert np.allclose(bilinear(image, np.float32([0, 1.5, 9]), np.float32([0, 1, 2])), [0, 5.5, 11])


def _bilinear_reference(image, x, y):
    """Point by point in Python floats: the four neighbours of the clamped point, the last pair of rows or
    columns at the far border, blended along x, then along y."""
    h, w = image.shape[:2]
    out = []
    for px, py in zip(x.tolist(), y.tolist()):
        px, py = min(max(px, 0.0), w - 1.0), min(max(py, 0.0), h - 1.0)
        c0, r0 = min(math.floor(px), max(w - 2, 0)), min(math.floor(py), max(h - 2, 0))
        c1, r1 = min(c0 + 1, w - 1), min(r0 + 1, h - 1)
        ax, ay = px - c0, py - r0
        top = image[r0, c0].astype(np.float64) * (1 - ax) + image[r0, c1].astype(np.float64) * ax
        bottom = image[r1, c0].astype(np.float64) * (1 - ax) + image[r1, c1].astype(np.float64) * ax
        out.append(top * (1 - ay) + bottom * ay)
    return np.asarray(out).astype(np.float32)


def test_bilinear_equals_a_point_by_point_reference_bit_for_bit():
    rng = np.random.default_rng(0)
    for shape in ((7, 5, 3), (6, 9), (1, 4, 3), (4, 1)):
        image = rng.random(shape, dtype=np.float32)
        x = rng.uniform(-2, shape[1] + 1, 500).astype(np.float32)
        y = rng.uniform(-2, shape[0] + 1, 500).astype(np.float32)
        x[:3], y[:3] = [0, shape[1] - 1, shape[1] - 1], [0, shape[0] - 1, 0]  # corners exactly
        strided = np.pad(image, [(1, 1), (1, 1)] + [(0, 0)] * (image.ndim - 2))[1:-1, 1:-1]  # not contiguous
        for img in (image, strided):
            assert np.array_equal(bilinear(img, x, y), _bilinear_reference(img, x, y)), shape


def test_an_occluded_texel_takes_no_color_from_the_view_that_cannot_see_it():
    # a small box hides the middle of a big face from camera 0 only; the camera 0 color there is red
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
    # where view 0 is the only one to see a texel it still gives the color (nothing better is at hand)
    alone = (plain.weight_maps[0] > 0) & (plain.weight_maps[1:].sum(0) == 0)
    assert alone.sum() > 10
    assert np.allclose(flagged.weight_maps[0][alone], 1.0)
