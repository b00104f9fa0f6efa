"""Rendering a textured mesh at any camera by ray casting (CPU, no GPU, no lighting: the baked texture
already holds the appearance the inputs showed), so it can be scored like the field's novel views."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from va_plugin.cameras import Cameras
from va_plugin.data.images import write_image
from va_plugin.errors import ConfigError
from va_plugin.eval.evaluate import image_metrics
from va_plugin.export.render import turntable_cameras, write_video
from va_plugin.export.views import bilinear
from va_plugin.raycast import MeshRenderer, SurfaceHits
from va_plugin.utils.memory import small_numpy_pages
from va_plugin.utils.progress import progress_bar


class UnlitMeshRenderer(MeshRenderer):
    """A :class:`MeshRenderer` whose hits show their albedo as it is (no light)."""

    def shade(self, face_ids: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """RGB ``[n, 3]`` in [0, 1] of ``n`` hits: their faces ``[n]`` and barycentric weights ``[n, 3]``."""
        corners = self.faces[face_ids]
        points = np.einsum("nk,nkc->nc", bary, self.rest_vertices[corners]).astype(np.float32)
        return np.clip(self.albedo(SurfaceHits(points, corners, bary.astype(np.float32))), 0.0, 1.0)


class BakedTexture:
    """Albedo of a :class:`va_plugin.export.baked.TexturedMesh`: its image sampled bilinearly at the hits'
    UVs, with texel centres where the baker put them (``uv = ((c + 0.5) / S, 1 - (r + 0.5) / S)``)."""

    def __init__(self, textured) -> None:
        self.uv = textured.uv
        self.image = textured.image

    def __call__(self, hits: SurfaceHits) -> np.ndarray:
        """RGB ``[n, 3]`` of ``n`` hits."""
        uv = np.einsum("nk,nkc->nc", hits.barycentric, self.uv[hits.corners])
        h, w = self.image.shape[:2]
        return bilinear(self.image, uv[:, 0] * w - 0.5, (1.0 - uv[:, 1]) * h - 0.5)


def textured_renderer(textured) -> UnlitMeshRenderer:
    """A renderer of a :class:`va_plugin.export.baked.TexturedMesh`."""
    import trimesh

    mesh = trimesh.Trimesh(textured.vertices, textured.faces, process=False)
    return UnlitMeshRenderer(mesh, BakedTexture(textured))


def render_on_background(renderer: MeshRenderer, cameras: Cameras, index: int, background=(1.0, 1.0, 1.0),
                         supersample: int = 2) -> np.ndarray:
    """RGB ``[H, W, 3]`` of view ``index`` composited on ``background`` (edges anti-aliased)."""
    rgba = renderer.render(cameras, index, supersample=supersample)
    bg = np.asarray(background, np.float32)
    return (rgba[..., :3] * rgba[..., 3:] + bg * (1.0 - rgba[..., 3:])).astype(np.float32)


SCORE_SUPERSAMPLE = 1
"""Rays per pixel side when a textured mesh is scored: one through each pixel centre, as the field's novel
views are rendered (more would also box-filter the texture)."""
MAX_SUPERSAMPLE = 8


def check_supersample(value: int, name: str = "supersample") -> int:
    """``value`` when it is a whole number in [1, MAX_SUPERSAMPLE], else ConfigError naming ``name``."""

    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_SUPERSAMPLE:
        raise ConfigError(f"{name} must be a whole number of rays per pixel side in [1, {MAX_SUPERSAMPLE}], "
                          f"got {value!r}")
    return int(value)


def textured_mesh_metrics(pipeline, textured, image_scale: float = 1.0, max_views=None, use_lpips: bool = True,
                          progress: bool = True, render_dir=None, supersample: int = SCORE_SUPERSAMPLE):
    """PSNR, SSIM and LPIPS of a textured mesh ray cast at the run's held-out views (``supersample^2`` rays
    a pixel), scored like the field's novel views (:func:`va_plugin.eval.evaluate.image_metrics`)."""

    supersample = check_supersample(supersample)
    renderer = textured_renderer(textured)
    background = pipeline.datamanager.test.background if pipeline.datamanager.test is not None else (1, 1, 1)
    return image_metrics(pipeline, image_scale, max_views, use_lpips, progress, render_dir,
                         render_fn=lambda cameras, i: render_on_background(renderer, cameras, i, background,
                                                                           supersample=supersample))


@small_numpy_pages()
def textured_turntable(textured, out_dir: Path, n_frames: int = 24, resolution: int = 256,
                       progress: bool = True) -> Path:
    """A turntable of a baked :class:`~va_plugin.export.baked.TexturedMesh` (ray cast, unlit, on white):
    ``turntable.mp4`` and ``turntable.png`` (four frames side by side) in ``out_dir``; the video's path."""

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    renderer = textured_renderer(textured)
    cameras = turntable_cameras(n_frames, resolution)
    frames = [render_on_background(renderer, cameras, k)
              for k in progress_bar(range(n_frames), desc="turntable", disable=not progress)]
    step = max(1, n_frames // 4)
    write_image(out_dir / "turntable.png", np.concatenate(frames[::step][:4], axis=1))
    return write_video(frames, out_dir / "turntable.mp4")
