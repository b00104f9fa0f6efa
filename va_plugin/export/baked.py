"""What a texture bake gives: the textured mesh and the bake's report (:mod:`va_plugin.export.texture` makes
them, :mod:`va_plugin.export.writing` writes them)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh


@dataclass
class TexturedMesh:
    """A mesh with per-vertex UVs and its texture."""

    vertices: np.ndarray  # [v, 3] float32 (split along UV seams)
    faces: np.ndarray  # [f, 3] int64
    uv: np.ndarray  # [v, 2] float32 in [0, 1], v up
    image: np.ndarray  # [S, S, 3] float32 RGB in [0, 1]

    def to_trimesh(self) -> trimesh.Trimesh:
        from PIL import Image

        texture = Image.fromarray((np.clip(self.image, 0, 1) * 255 + 0.5).astype(np.uint8))
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=texture, metallicFactor=0.0,
                                                       roughnessFactor=1.0, name="baked")
        visual = trimesh.visual.TextureVisuals(uv=self.uv, material=material)
        return trimesh.Trimesh(self.vertices, self.faces, visual=visual, process=False)


@dataclass
class BakeReport:
    """What the bake did: per-view weight maps in texture space and counts."""

    weight_maps: np.ndarray  # [n, S, S] share of each view in each texel's color
    covered: int  # texels on the surface
    seen: int  # of those, texels at least one view sees
    view_texels: list[int]  # texels each view sees
    seconds: dict[str, float] = field(default_factory=dict)
    gains: np.ndarray | None = None  # [n, 3] per-view color gain of the harmonisation (None: off)

    def summary(self) -> dict[str, object]:
        total = np.maximum(self.weight_maps.sum(0), 1e-12)
        share = [float(m.sum() / max(total[total > 1e-12].size, 1)) for m in self.weight_maps]
        out = {"texels_on_surface": self.covered, "texels_seen": self.seen,
               "texels_fallback": self.covered - self.seen, "view_texels": self.view_texels,
               "view_share": [round(s, 4) for s in share],
               "seconds": {k: round(v, 2) for k, v in self.seconds.items()}}
        if self.gains is not None:
            out["view_color_gain"] = np.round(self.gains, 4).tolist()
        return out
