"""mesh_views: grey renders of meshes, one row per mesh."""

import numpy as np
import trimesh

from va_plugin.export.render import mesh_views, turntable_cameras


def test_a_sphere_covers_the_disc_its_projection_predicts():
    radius = 0.3
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    small = trimesh.creation.icosphere(subdivisions=4, radius=radius / 2)
    image = mesh_views([sphere, small], n_views=2, resolution=48)
    assert image.shape == (96, 96, 3)
    cameras = turntable_cameras(2, 48)
    distance = float(cameras.c2w[0, :3, 3].norm())
    focal = float(cameras.fx[0]) if cameras.fx.ndim else float(cameras.fx)
    for row, r in ((0, radius), (1, radius / 2)):
        tile = image[row * 48:(row + 1) * 48, :48]
        covered = float((tile.mean(-1) < 0.99).mean())
        # apparent radius of a sphere at distance d: f * r / sqrt(d^2 - r^2) pixels
        expected = np.pi * (focal * r / np.sqrt(distance**2 - r**2)) ** 2 / 48**2
        assert abs(covered - expected) < 0.15 * expected
    # a sphere's silhouette is the same from every azimuth (its shading is not: the light is fixed)
    masks = [image[:48, c:c + 48].mean(-1) < 0.99 for c in (0, 48)]
    assert (masks[0] != masks[1]).mean() < 0.01
