"""Hand-made texture cases shared by the export tests: a cube whose colors are known everywhere, seen by
known cameras."""

import numpy as np
import trimesh

from va_plugin.data.rigs import orbit_cameras
from va_plugin.eval.mesh_render import UnlitMeshRenderer
from va_plugin.export.atlas import rasterize_uv
from va_plugin.export.views import Views

RES = 48
TEXTURE = 64


def smooth_color(points: np.ndarray) -> np.ndarray:
    """A color that varies slowly over the cube (so bilinear sampling errors stay small)."""
    return np.clip(0.5 + 0.8 * points[:, [0, 1, 2]] * np.array([1.0, -1.0, 1.0]), 0.0, 1.0).astype(np.float32)


def cube(size: float = 0.6) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(size, size, size))


def cube_views(mesh, azimuths, elevations, color=smooth_color):
    cameras = orbit_cameras(azimuths, elevations, resolution=RES, pixel_offset=0.5)
    renderer = UnlitMeshRenderer(mesh, lambda hits: color(hits.points))
    images, masks = [], []
    for k in range(len(cameras)):
        rgba = renderer.render(cameras, k, supersample=3)
        images.append(rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:]))
        masks.append(rgba[..., 3] > 0.5)
    return Views(cameras, np.stack(images).astype(np.float32), np.stack(masks))


def texel_truth(textured):
    """Per covered texel: its known color, from where it lies on the surface."""
    face, bary = rasterize_uv(textured.uv, textured.faces, TEXTURE)
    covered = face >= 0
    corners = textured.faces[face[covered]]
    points = np.einsum("mk,mkc->mc", bary[covered], textured.vertices[corners])
    return covered, points


SIX_SIDES = dict(azimuths=[0, 90, 180, 270, 45, 135, 225, 315, 45, 225], elevations=[20] * 4 + [0] * 4 + [80, -80])
