"""Our fields behind nerfstudio's ``Field``: for code that queries a field with nerfstudio's ``RaySamples``.

Our models render with our own samplers and hand our fields our samples; this adapter answers
nerfstudio's calls with the same field: a density field gives ``DENSITY`` (InstantNGP's truncated
exponential of its raw output) and ``RGB``; an SDF field gives ``SDF``, ``GRADIENT``, ``NORMALS`` and
``RGB`` from ``get_outputs`` and, like nerfstudio's own SDF field, no ``get_density``. The samples'
``camera_indices`` pick the training view of the view-adaptive field's branches (-1 or none: the
canonical color of novel views).
"""

from __future__ import annotations

import torch
from nerfstudio.cameras.rays import RaySamples
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.fields.base_field import Field

from va_plugin.fields.base import Field as VAFieldBase
from va_plugin.fields.density_field import trunc_exp

NOVEL_VIEW = -1


class VAField(Field):
    """nerfstudio's view of one of our fields (``va_field``, not a submodule: its model holds it)."""

    def __init__(self, va_field: VAFieldBase) -> None:
        super().__init__()
        object.__setattr__(self, "va_field", va_field)

    def _inputs(self, ray_samples: RaySamples) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Positions and unit directions ``[n, 3]`` and camera indices ``[n]`` of the samples, flattened."""
        positions = ray_samples.frustums.get_positions().reshape(-1, 3)
        directions = torch.nn.functional.normalize(ray_samples.frustums.directions.reshape(-1, 3), dim=-1)
        if ray_samples.camera_indices is None:
            cameras = torch.full(positions.shape[:1], NOVEL_VIEW, dtype=torch.long, device=positions.device)
        else:
            cameras = ray_samples.camera_indices.reshape(-1).long()
        return positions, directions, cameras

    def get_density(self, ray_samples: RaySamples) -> tuple[torch.Tensor, torch.Tensor]:
        if self.va_field.geometry_kind == "sdf":
            raise NotImplementedError("an SDF field has no density of its own: use get_outputs (FieldHeadNames.SDF)")
        positions = self._inputs(ray_samples)[0]
        raw, features = self.va_field.geometry(positions)
        shape = ray_samples.frustums.shape
        return trunc_exp(raw).reshape(*shape, 1), features.reshape(*shape, -1)

    def get_outputs(self, ray_samples: RaySamples, density_embedding: torch.Tensor | None = None
                    ) -> dict[FieldHeadNames, torch.Tensor]:
        positions, directions, cameras = self._inputs(ray_samples)
        shape = ray_samples.frustums.shape
        if self.va_field.geometry_kind != "sdf":
            features = density_embedding.reshape(positions.shape[0], -1) if density_embedding is not None \
                else self.va_field.geometry(positions)[1]
            rgb = self.va_field.color(positions, directions, torch.zeros_like(positions), features, cameras)["rgb"]
            return {FieldHeadNames.RGB: rgb.reshape(*shape, 3)}
        with torch.enable_grad():
            positions = positions.detach().requires_grad_(True)
            sdf, features = self.va_field.geometry(positions)
            gradient, = torch.autograd.grad(sdf.sum(), positions, create_graph=self.training)
        normals = torch.nn.functional.normalize(gradient, dim=-1, eps=1e-6)
        rgb = self.va_field.color(positions, directions, normals, features, cameras)["rgb"]
        return {FieldHeadNames.SDF: sdf.reshape(*shape, 1), FieldHeadNames.GRADIENT: gradient.reshape(*shape, 3),
                FieldHeadNames.NORMALS: normals.reshape(*shape, 3), FieldHeadNames.RGB: rgb.reshape(*shape, 3)}

    def forward(self, ray_samples: RaySamples, compute_normals: bool = False) -> dict[FieldHeadNames, torch.Tensor]:
        if self.va_field.geometry_kind == "sdf":
            return self.get_outputs(ray_samples)
        return super().forward(ray_samples, compute_normals=compute_normals)
