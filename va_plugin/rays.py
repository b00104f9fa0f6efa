"""Rays and samples along rays."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import torch


@dataclass
class RayBundle:
    """A batch of rays.

    Attributes:
        origins: ``[n_rays, 3]``.
        directions: ``[n_rays, 3]`` unit vectors.
        camera_indices: ``[n_rays]`` long, the training view each ray comes from (-1 for novel views).
        nears, fars: ``[n_rays, 1]`` where the ray enters and leaves the scene bound (filled by the model).
    """

    origins: torch.Tensor
    directions: torch.Tensor
    camera_indices: torch.Tensor
    nears: Optional[torch.Tensor] = None
    fars: Optional[torch.Tensor] = None

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index) -> "RayBundle":
        pick = lambda t: None if t is None else t[index]  # noqa: E731
        return RayBundle(self.origins[index], self.directions[index], self.camera_indices[index],
                         pick(self.nears), pick(self.fars))

    def to(self, device: torch.device) -> "RayBundle":
        move = lambda t: None if t is None else t.to(device)  # noqa: E731
        return RayBundle(self.origins.to(device), self.directions.to(device), self.camera_indices.to(device),
                         move(self.nears), move(self.fars))


@dataclass
class RaySamples:
    """Samples along rays: section mid-points ``t_mid`` with lengths ``deltas``.

    Attributes:
        positions: ``[n_rays, n_samples, 3]`` at the section mid-points.
        directions: ``[n_rays, 3]`` unit ray directions.
        t_mid: ``[n_rays, n_samples]`` distances of the mid-points along the ray.
        deltas: ``[n_rays, n_samples]`` section lengths.
        camera_indices: ``[n_rays]`` long.
    """

    positions: torch.Tensor
    directions: torch.Tensor
    t_mid: torch.Tensor
    deltas: torch.Tensor
    camera_indices: torch.Tensor

    @staticmethod
    def from_edges(ray_bundle: RayBundle, t_edges: torch.Tensor) -> "RaySamples":
        """Samples between consecutive section edges ``t_edges [n_rays, n_samples + 1]``."""
        deltas = t_edges[:, 1:] - t_edges[:, :-1]
        t_mid = t_edges[:, :-1] + 0.5 * deltas
        positions = ray_bundle.origins[:, None, :] + ray_bundle.directions[:, None, :] * t_mid[..., None]
        return RaySamples(positions, ray_bundle.directions, t_mid, deltas, ray_bundle.camera_indices)


def near_far_from_sphere(origins: torch.Tensor, directions: torch.Tensor, radius: float,
                         min_near: float = 0.0) -> Tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where rays enter and leave a sphere of ``radius`` at the origin.

    Computed from the point of closest approach ``p = o + t_c d`` rather than the textbook
    discriminant ``b^2 - 4ac``: for a camera far from the sphere the latter subtracts two huge, nearly
    equal numbers and loses every digit in fp32 (a camera 10^4 radii away missed the sphere).

    Args:
        origins, directions: ``[n_rays, 3]``; directions need not be unit length. A zero-length
            direction (below 1e-6) is a ray that goes nowhere: it misses.
    Returns:
        nears, fars ``[n_rays, 1]`` and ``hits [n_rays]`` (bool). Rays that miss get near = far, so
        every sample interval on them has zero length and they render background.
    """
    a = (directions * directions).sum(-1)
    usable = a > 1e-12
    a = torch.where(usable, a, torch.ones_like(a))
    t_closest = -(origins * directions).sum(-1) / a
    closest = origins + t_closest[:, None] * directions
    half_chord_sq = (radius * radius - (closest * closest).sum(-1)) / a
    hits = usable & (half_chord_sq > 0)
    half_chord = torch.sqrt(half_chord_sq.clamp_min(0.0))
    near = (t_closest - half_chord).clamp_min(min_near)
    far = t_closest + half_chord
    hits = hits & (far > near)
    far = torch.where(hits, far, near)
    return near[:, None], far[:, None], hits


def isotropic_rays(n_rays: int, radius: float, device: torch.device | str = "cpu") -> RayBundle:
    """``n_rays`` novel-view rays (camera index -1) through a sphere of ``radius`` at the origin, uniform
    over the lines that meet it: a direction uniform on the unit sphere, then a point uniform on the disk of
    ``radius`` through the origin across that direction. The mean opacity of such rays is the object's
    silhouette area averaged over all viewing directions, divided by the disk's area (for a convex body a
    quarter of its surface area, by Cauchy's formula). Origins sit ``2 radius`` back from the disk, outside
    the sphere."""
    directions = torch.randn(n_rays, 3).to(device)
    directions = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    # an axis not parallel to the direction, then two unit vectors across it
    helper = torch.zeros_like(directions)
    helper[:, 2] = 1.0
    near_z = directions[:, 2].abs() > 0.9
    helper[near_z] = torch.tensor([1.0, 0.0, 0.0], device=directions.device)
    u = torch.cross(directions, helper, dim=-1)
    u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    v = torch.cross(directions, u, dim=-1)
    uniform = torch.rand(n_rays, 2).to(device)
    r = radius * uniform[:, :1].sqrt()
    angle = 2.0 * torch.pi * uniform[:, 1:]
    points = r * (angle.cos() * u + angle.sin() * v)
    origins = points - 2.0 * radius * directions
    return RayBundle(origins, directions, torch.full((n_rays,), -1, dtype=torch.long, device=directions.device))
