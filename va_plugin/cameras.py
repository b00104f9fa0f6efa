"""Pinhole and orthographic cameras, and ray generation.

Conventions (one place, stated once):

* ``c2w`` is camera-to-world ``[n, 3, 4]`` in **OpenCV axes**: camera x right, y down, z forward
  (the camera looks along +z). OpenGL/Blender matrices (x right, y up, z backward, as in
  ``transforms.json``) are converted on load with :func:`opengl_to_opencv`.
* Pixel ``(row v, column u)`` is sampled at image-plane coordinate ``(u + pixel_offset, v + pixel_offset)``.
  ``pixel_offset = 0.5`` means pixel centres sit half a pixel in (nerfstudio, Blender, our scenes);
  ``0.0`` means integer coordinates are pixel centres (SyncDreamer's rig: ``K @ X_cam`` with no offset).
* Perspective: ``u = fx * X/Z + cx - pixel_offset``. Orthographic: ``u = fx * X + cx - pixel_offset``
  where ``fx`` is pixels per world unit and every ray of a view shares the direction +z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from va_plugin.errors import DataError

PERSPECTIVE = "perspective"
ORTHOGRAPHIC = "orthographic"

_GL_TO_CV = torch.tensor([1.0, -1.0, -1.0])


def opengl_to_opencv(c2w: torch.Tensor) -> torch.Tensor:
    """Flip the y and z camera axes of ``[..., 3, 4]`` (or 4x4) camera-to-world matrices."""
    out = c2w.clone()
    out[..., :3, :3] = out[..., :3, :3] * _GL_TO_CV.to(c2w)
    return out


def look_at(eye: torch.Tensor, target: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """OpenCV camera-to-world ``[n, 3, 4]`` for cameras at ``eye [n, 3]`` looking at ``target [n, 3]``."""
    forward = torch.nn.functional.normalize(target - eye, dim=-1)
    right = torch.nn.functional.normalize(torch.cross(forward, up.expand_as(forward), dim=-1), dim=-1)
    down = torch.cross(forward, right, dim=-1)
    return torch.stack([right, down, forward, eye], dim=-1)


@dataclass
class Cameras:
    """A set of ``n`` cameras sharing one image size."""

    c2w: torch.Tensor  # [n, 3, 4] camera-to-world, OpenCV axes
    fx: torch.Tensor  # [n] intrinsics in pixels (orthographic fx, fy: pixels per world unit)
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    width: int  # image size in pixels
    height: int
    camera_type: str = PERSPECTIVE  # or ORTHOGRAPHIC
    pixel_offset: float = 0.5  # where a pixel is sampled, see the module docstring

    def __post_init__(self) -> None:
        n = self.c2w.shape[0]
        self.c2w = self.c2w.float()
        for name in ("fx", "fy", "cx", "cy"):
            value = torch.as_tensor(getattr(self, name), dtype=torch.float32).reshape(-1)
            if value.numel() == 1:
                value = value.expand(n).clone()
            setattr(self, name, value)
        if self.camera_type not in (PERSPECTIVE, ORTHOGRAPHIC):
            raise DataError(f"unknown camera type {self.camera_type!r}; use perspective or orthographic")
        validate_poses(self.c2w)
        if not (torch.isfinite(self.fx).all() and (self.fx > 0).all() and (self.fy > 0).all()):
            raise DataError("camera focal lengths must be finite and positive")

    def __len__(self) -> int:
        return self.c2w.shape[0]

    @property
    def centers(self) -> torch.Tensor:
        """Camera positions ``[n, 3]``."""
        return self.c2w[:, :, 3]

    def to(self, device: torch.device) -> Cameras:
        return Cameras(self.c2w.to(device), self.fx.to(device), self.fy.to(device), self.cx.to(device),
                       self.cy.to(device), self.width, self.height, self.camera_type, self.pixel_offset)

    def subset(self, indices) -> Cameras:
        """The cameras at ``indices`` (a list or long tensor)."""
        idx = torch.as_tensor(indices, dtype=torch.long)
        return Cameras(self.c2w[idx], self.fx[idx], self.fy[idx], self.cx[idx], self.cy[idx],
                       self.width, self.height, self.camera_type, self.pixel_offset)

    def scaled(self, factor: float) -> Cameras:
        """The same cameras for images resized by ``factor`` (exact for ``pixel_offset = 0.5``, else
        within half a pixel)."""
        width, height = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = width / self.width, height / self.height
        return Cameras(self.c2w, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height,
                       self.camera_type, self.pixel_offset)

    def generate_rays(self, camera_indices: torch.Tensor | int, rows: torch.Tensor, cols: torch.Tensor
                      ) -> tuple[torch.Tensor, torch.Tensor]:
        """World origins ``[n_rays, 3]`` and unit directions ``[n_rays, 3]`` of the rays through pixels
        ``rows, cols`` ``[n_rays]`` (float allowed) of the views ``camera_indices`` ``[n_rays]``, or of the
        one view ``camera_indices`` when it is an int (no per-ray copy of the pose)."""
        if isinstance(camera_indices, (int, np.integer)):
            index = int(camera_indices)
            c2w = self.c2w[index][None]
            fx, fy, cx, cy = self.fx[index], self.fy[index], self.cx[index], self.cy[index]
        else:
            c2w = self.c2w[camera_indices]
            fx, fy = self.fx[camera_indices], self.fy[camera_indices]
            cx, cy = self.cx[camera_indices], self.cy[camera_indices]
        x = ((cols.float() + self.pixel_offset - cx) / fx)[:, None]
        y = ((rows.float() + self.pixel_offset - cy) / fy)[:, None]
        shape = (x.shape[0], 3)
        # the rotation's columns times the camera-frame offset (x, y, 1) or (x, y, 0), summed in that order
        across = c2w[:, :, 0] * x + c2w[:, :, 1] * y
        position = c2w[:, :, 3]
        if self.camera_type == PERSPECTIVE:
            directions = torch.nn.functional.normalize(across + c2w[:, :, 2], dim=-1)
            return position.expand(shape).contiguous(), directions
        return position + across, c2w[:, :, 2].expand(shape).contiguous()

    def pixel_grid(self, camera_index: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Camera indices, rows and columns of every pixel of one view, row-major ``[H*W]``."""
        device = self.c2w.device
        rows, cols = torch.meshgrid(torch.arange(self.height, device=device),
                                    torch.arange(self.width, device=device), indexing="ij")
        rows, cols = rows.reshape(-1), cols.reshape(-1)
        return torch.full_like(rows, camera_index), rows, cols

    def project(self, points: torch.Tensor, camera_index: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Project world points ``[m, 3]`` into one view: ``uv [m, 2]`` (column, row) in pixel-index
        coordinates, and depth ``[m]`` along +z."""
        c2w = self.c2w[camera_index]
        rotation, position = c2w[:, :3], c2w[:, 3]
        local = (points - position) @ rotation
        depth = local[:, 2]
        if self.camera_type == PERSPECTIVE:
            safe = torch.where(depth.abs() < 1e-9, torch.full_like(depth, 1e-9), depth)
            x, y = local[:, 0] / safe, local[:, 1] / safe
        else:
            x, y = local[:, 0], local[:, 1]
        u = self.fx[camera_index] * x + self.cx[camera_index] - self.pixel_offset
        v = self.fy[camera_index] * y + self.cy[camera_index] - self.pixel_offset
        return torch.stack([u, v], dim=-1), depth


def validate_poses(c2w: torch.Tensor) -> None:
    """Refuse poses that are not finite rigid transforms, with a message naming the first bad view."""
    if c2w.ndim != 3 or c2w.shape[1:] != (3, 4):
        raise DataError(f"camera poses must have shape [n, 3, 4], got {list(c2w.shape)}")
    for i in range(c2w.shape[0]):
        if not torch.isfinite(c2w[i]).all():
            raise DataError(f"camera {i}: pose contains NaN or infinite values")
        rotation = c2w[i, :, :3].double()
        gram = rotation.T @ rotation
        if (gram - torch.eye(3, dtype=gram.dtype, device=gram.device)).abs().max() > 1e-3:
            raise DataError(f"camera {i}: pose rotation is not orthonormal (scaled, sheared or singular)")
        if torch.det(rotation) < 0:
            raise DataError(f"camera {i}: pose rotation is a reflection (determinant -1)")
