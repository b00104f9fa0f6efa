"""Rays and samples along rays."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RayBundle:
    """A batch of rays."""

    origins: torch.Tensor  # [n_rays, 3]
    directions: torch.Tensor  # [n_rays, 3] unit vectors
    camera_indices: torch.Tensor  # [n_rays] long: the training view of each ray (-1: novel view)
    nears: torch.Tensor | None = None  # [n_rays, 1] where the ray enters the scene bound (set by the model)
    fars: torch.Tensor | None = None  # [n_rays, 1] where it leaves it

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index) -> RayBundle:
        pick = lambda t: None if t is None else t[index]
        return RayBundle(self.origins[index], self.directions[index], self.camera_indices[index],
                         pick(self.nears), pick(self.fars))

    def to(self, device: torch.device) -> RayBundle:
        move = lambda t: None if t is None else t.to(device)
        return RayBundle(self.origins.to(device), self.directions.to(device), self.camera_indices.to(device),
                         move(self.nears), move(self.fars))


@dataclass
class RaySamples:
    """Samples along rays: section mid-points ``t_mid`` with lengths ``deltas``."""

    positions: torch.Tensor  # [n_rays, n_samples, 3] at the section mid-points
    directions: torch.Tensor  # [n_rays, 3] unit ray directions
    t_mid: torch.Tensor  # [n_rays, n_samples] distances of the mid-points along the ray
    deltas: torch.Tensor  # [n_rays, n_samples] section lengths
    camera_indices: torch.Tensor  # [n_rays] long

    @staticmethod
    def from_edges(ray_bundle: RayBundle, t_edges: torch.Tensor) -> RaySamples:
        """Samples between consecutive section edges ``t_edges [n_rays, n_samples + 1]``."""
        deltas = t_edges[:, 1:] - t_edges[:, :-1]
        t_mid = t_edges[:, :-1] + 0.5 * deltas
        positions = ray_bundle.origins[:, None, :] + ray_bundle.directions[:, None, :] * t_mid[..., None]
        return RaySamples(positions, ray_bundle.directions, t_mid, deltas, ray_bundle.camera_indices)


def near_far_from_sphere(origins: torch.Tensor, directions: torch.Tensor, radius: float,
                         min_near: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where rays enter and leave a sphere of ``radius`` at the origin, from the point of closest
    approach (the textbook discriminant loses every digit in fp32 for a far camera).

    Args:
        origins, directions: ``[n_rays, 3]``; directions need not be unit length (zero length: a miss).
    Returns:
        nears, fars ``[n_rays, 1]`` and ``hits [n_rays]`` (bool); a miss gets near = far.
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
    """``n_rays`` novel-view rays (camera index -1) uniform over the lines that meet a sphere of ``radius``
    at the origin: a uniform direction, then a uniform point on the disk across it; origins sit
    ``2 radius`` back, outside the sphere."""
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
