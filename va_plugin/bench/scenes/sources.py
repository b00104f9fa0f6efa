"""Where a scene's clean and inconsistent views come from.

* ``procedural:NAME``: an object of :mod:`shapes`, rendered by ray casting (any camera).
* ``mesh:PATH``: a textured mesh file, rendered the same way (see :mod:`meshfile`).
* ``gso:NAME``: a Google Scanned Object; its 16 rig renders are the clean views (no renderer of its real
  appearance exists), and the aligned mesh serves as ground truth and as depth for pose errors.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
import trimesh
from scipy import ndimage

from va_plugin.bench.scenes import gso, meshfile, shapes
from va_plugin.bench.scenes.inconsistency import (
    ViewPerturbation,
    apply_appearance,
    compose_maps,
    displacement_map,
    perturbed_vertices,
    remap_rgba,
)
from va_plugin.bench.scenes.rig import RIG_DISTANCE
from va_plugin.cameras import Cameras, look_at
from va_plugin.errors import ConfigError
from va_plugin.eval.mesh_render import textured_renderer
from va_plugin.export.texture import bake_texture
from va_plugin.export.views import Views
from va_plugin.raycast import MeshRenderer, position_albedo

SOURCE_KINDS = ("procedural", "mesh", "gso")


def perturbed_camera(cameras: Cameras, index: int, orbit_deg) -> Cameras:
    """View ``index`` moved on its orbit around the origin by ``(d_azimuth, d_elevation, roll)`` degrees,
    as a one-camera :class:`Cameras` looking at the origin (before the roll)."""
    d_az, d_el, roll = (math.radians(float(v)) for v in orbit_deg)
    eye = cameras.c2w[index, :, 3].double()
    distance = float(eye.norm())
    azimuth = math.atan2(float(eye[1]), float(eye[0])) + d_az
    elevation = math.asin(float(eye[2]) / distance) + d_el
    new_eye = distance * torch.tensor([[math.cos(elevation) * math.cos(azimuth),
                                        math.cos(elevation) * math.sin(azimuth), math.sin(elevation)]],
                                      dtype=torch.float64)
    c2w = look_at(new_eye, torch.zeros_like(new_eye), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    spin = torch.tensor([[math.cos(roll), -math.sin(roll), 0.0], [math.sin(roll), math.cos(roll), 0.0],
                         [0.0, 0.0, 1.0]], dtype=torch.float64)
    c2w[0, :, :3] = c2w[0, :, :3] @ spin
    i = [index]
    return Cameras(c2w.float(), cameras.fx[i], cameras.fy[i], cameras.cx[i], cameras.cy[i], cameras.width,
                   cameras.height, cameras.camera_type, cameras.pixel_offset)


BAKED_TEXTURE_SIZE = 1024
BAKED_MAX_FACES = 100_000
"""Faces of the ground-truth mesh kept for the baked off-rig views (the geometry scores use the whole mesh)."""


class SceneSource:
    """A benchmark object: ground-truth mesh, clean views, and inconsistent input views."""

    spec: str
    description: str
    ground_truth: trimesh.Trimesh
    renderable: bool  # False: only the 16 rig views exist
    _info: ClassVar[dict[str, Any]] = {}

    def clean(self, cameras: Cameras, view: int) -> np.ndarray:
        """Straight-alpha RGBA ``[H, W, 4]`` of view ``view``."""
        raise NotImplementedError

    def perturbed(self, cameras: Cameras, view: int, p: ViewPerturbation) -> np.ndarray:
        """The inconsistent version of view ``view``, ``[H, W, 4]``."""
        raise NotImplementedError

    def normals(self, cameras: Cameras, view: int, p: ViewPerturbation | None = None) -> np.ndarray:
        """Normal map ``[H, W, 4]`` of view ``view`` (perturbed by ``p``: moved on its orbit, the surface
        displaced): unit normals in the OpenCV axes of the camera that saw them, then coverage."""
        raise NotImplementedError(f"{type(self).__name__} renders no normal maps")

    def info(self) -> dict[str, Any]:
        """Extra facts for scene.json."""
        return dict(self._info)


class RenderedSource(SceneSource):
    """A mesh with an albedo, rendered by ray casting from any camera."""

    renderable = True

    def __init__(self, spec: str, description: str, renderer: MeshRenderer, ground_truth: trimesh.Trimesh,
                 info: dict[str, Any] | None = None) -> None:
        self.spec, self.description, self.renderer = spec, description, renderer
        self.ground_truth = ground_truth
        self._info = info or {}

    def clean(self, cameras: Cameras, view: int) -> np.ndarray:
        return self.renderer.render(cameras, view)

    def perturbed(self, cameras: Cameras, view: int, p: ViewPerturbation) -> np.ndarray:
        renderer, camera = self._seen(cameras, view, p)
        return apply_appearance(renderer.render(camera, 0), p)

    def normals(self, cameras: Cameras, view: int, p: ViewPerturbation | None = None) -> np.ndarray:
        renderer, camera = self._seen(cameras, view, p)
        world = renderer.normals(camera, 0)
        rotation = camera.c2w[0, :, :3].numpy()
        return np.concatenate([world[..., :3] @ rotation, world[..., 3:]], -1).astype(np.float32)

    def _seen(self, cameras: Cameras, view: int, p: ViewPerturbation | None) -> tuple[MeshRenderer, Cameras]:
        """The renderer (its surface displaced by ``p``) and the one camera (moved on its orbit by ``p``)
        that draw view ``view``; ``p`` None: the clean ones."""
        renderer = self.renderer
        if p is not None and p.displacement is not None:
            renderer = renderer.deformed(perturbed_vertices(renderer.rest_vertices, p))
        moved = p is not None and p.orbit_deg is not None
        return renderer, perturbed_camera(cameras, view, p.orbit_deg) if moved else cameras.subset([view])


class ImageSource(SceneSource):
    """Fixed renders on the rig ``[16, H, W, 4]`` with an aligned mesh; perturbed by resampling. Views off
    the rig show the mesh with a texture baked from the 16 renders (see :meth:`baked_renderer`)."""

    def __init__(self, spec: str, description: str, images: np.ndarray, ground_truth: trimesh.Trimesh,
                 info: dict[str, Any] | None = None, off_rig: bool = False) -> None:
        """``off_rig``: the source also renders the views off the rig (baked), so scenes hold them out too."""
        self.renderable = off_rig
        self.spec, self.description, self.images = spec, description, images
        self.ground_truth = ground_truth
        self.depth_renderer = MeshRenderer(ground_truth, lambda hits: np.zeros((len(hits.points), 3), np.float32))
        self._info = info or {}
        self._baked: MeshRenderer | None = None

    def clean(self, cameras: Cameras, view: int) -> np.ndarray:
        if view < len(self.images):
            return self.images[view]
        return self.baked_renderer(cameras.subset(list(range(len(self.images))))).render(cameras, view)

    def baked_renderer(self, rig: Cameras) -> MeshRenderer:
        """The mesh with a texture baked from the rig renders (``rig``: their cameras; weighted mean of
        the views that see a texel): an estimate of the object's look from off the rig, faithful where the
        rig sees the surface (the renders carry the only appearance there is). Texels the rig does not see
        take the padding of the atlas (``fill_unseen=False``), so the targets stay those every benchmark
        row was scored on, whatever the exported textures fill them with."""
        if self._baked is None:

            alpha = self.images[..., 3:]
            views = Views(rig, (self.images[..., :3] * alpha + (1.0 - alpha)).astype(np.float32))
            textured, _ = bake_texture(self.ground_truth, views, size=BAKED_TEXTURE_SIZE, fusion="mean",
                                       max_faces=BAKED_MAX_FACES, fill_unseen=False)
            self._baked = textured_renderer(textured)
        return self._baked

    def pose_map(self, cameras: Cameras, view: int, orbit_deg) -> np.ndarray:
        """For each pixel of the perturbed view, where it lies in the nominal view ``[H, W, 2]``, through
        the aligned mesh's depth (pixels that miss borrow the nearest hit's ray distance)."""
        camera = perturbed_camera(cameras, view, orbit_deg)
        origins, directions = self.depth_renderer.pixel_rays(camera, 0, 0.0, 0.0)
        t, _, _ = self.depth_renderer.cast(origins, directions)
        hit = np.isfinite(t)
        if not hit.any():
            t = np.full_like(t, RIG_DISTANCE)
        elif not hit.all():
            grid = hit.reshape(camera.height, camera.width)
            _, (rows, cols) = ndimage.distance_transform_edt(~grid, return_indices=True)
            t = t.reshape(grid.shape)[rows, cols].reshape(-1)
        points = torch.from_numpy((origins + directions * t[:, None]).astype(np.float32))
        uv, _ = cameras.project(points, view)
        return uv.numpy().reshape(camera.height, camera.width, 2)

    def sampling_map(self, cameras: Cameras, view: int, p: ViewPerturbation) -> np.ndarray | None:
        """Where each pixel of the perturbed view reads the clean render ``[H, W, 2]`` (the orbit error's
        map composed with the 2-D warp), or None when ``p`` moves nothing."""
        coords = None
        if p.orbit_deg is not None:
            coords = self.pose_map(cameras, view, p.orbit_deg)
        if p.displacement_2d is not None:
            pixels_per_unit = float(cameras.fx[view]) / RIG_DISTANCE
            warp = displacement_map(p.displacement_2d, cameras.height, cameras.width, pixels_per_unit)
            coords = warp if coords is None else compose_maps(coords, warp)
        return coords

    def perturbed(self, cameras: Cameras, view: int, p: ViewPerturbation) -> np.ndarray:
        coords = self.sampling_map(cameras, view, p)
        image = self.images[view] if coords is None else remap_rgba(self.images[view], coords)
        return apply_appearance(image, p)


def split_spec(spec: str):
    """``("procedural", "mug")`` from ``"procedural:mug"``; a bare procedural name is accepted too."""
    if ":" not in spec:
        if spec in shapes.OBJECTS:
            return "procedural", spec
        raise ConfigError(f"source must be procedural:NAME, mesh:PATH or gso:NAME, got {spec!r}")
    kind, _, name = spec.partition(":")
    if kind not in SOURCE_KINDS or not name:
        raise ConfigError(f"source must be procedural:NAME, mesh:PATH or gso:NAME, got {spec!r}")
    return kind, name


def load_source(spec: str, resolution: int = 256, data_root: Path | None = None, mesh_resolution: int = 160,
                up_axis: str = "y", yaw_deg: float = 0.0, texture: Path | None = None,
                gso_off_rig: bool = False) -> SceneSource:
    """The source named by ``spec`` (see the module docstring); ``data_root`` is the GSO folder.
    ``gso_off_rig``: a GSO object renders views off the rig too (baked; the paper's protocol has none)."""
    kind, name = split_spec(spec)
    if kind == "procedural":
        obj = shapes.get_object(name)
        mesh = shapes.object_mesh(name, mesh_resolution)
        return RenderedSource(f"procedural:{name}", obj.description, MeshRenderer(mesh, position_albedo(obj.texture)),
                              mesh, {"mesh_resolution": mesh_resolution})
    if kind == "mesh":
        textured = meshfile.load_textured_mesh(Path(name), texture, up_axis, yaw_deg)
        texture_file = None if textured.texture_path is None else str(textured.texture_path)
        info = {"mesh_file": str(name), "texture": texture_file, "up_axis": up_axis, "yaw_deg": yaw_deg}
        return RenderedSource(f"mesh:{name}", f"textured mesh {Path(name).name}",
                              MeshRenderer(textured.render_mesh, textured.albedo), textured.ground_truth, info)
    if data_root is None:
        raise ConfigError("a gso: source needs data_root (--data-root), the folder of the GSO objects")
    images = gso.load_renders(Path(data_root), name, resolution)
    mesh = gso.load_mesh(Path(data_root), name)
    info = {"data_root": str(data_root), "alignment_deg": gso.alignment_angle(Path(data_root), name)}
    return ImageSource(f"gso:{name}", f"Google Scanned Object {name} (renders on the SyncDreamer rig)",
                       images, mesh, info, off_rig=gso_off_rig)
