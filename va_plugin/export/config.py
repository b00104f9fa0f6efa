"""How a run's mesh is exported: :class:`ExportConfig` (the marching-cubes grid, the texture, its face
count, fusion and frame), the single source of those defaults for the API, the commands, the app and
``va-batch``, and the checks that refuse an option before any work (one line each)."""

from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass, fields, replace
from typing import Any

from va_plugin.config import Checked
from va_plugin.errors import ConfigError, VAError
from va_plugin.export.atlas import MAX_TEXTURE_FACES
from va_plugin.export.frame import check_frame
from va_plugin.export.fusion import FUSIONS
from va_plugin.utils.arguments import check_kinds
from va_plugin.utils.memory import check_mesh_resolution

MIN_TEXTURE_SIZE = 16
MAX_TEXTURE_SIZE = 8192
"""Largest texture side accepted (far more texels than any input view has pixels)."""
MIN_MESH_RESOLUTION = 8
"""Coarsest marching-cubes grid accepted (a coarser one cannot hold an object's shape)."""
FACES_MAX_RESOLUTION = 384
"""Finest marching-cubes grid that :func:`~va_plugin.export.mesh.mesh_for_faces` extracts to reach a ``faces``
count."""
MAX_FACES = 2_000_000
"""Most faces ``faces`` may ask for: a surface on the :data:`FACES_MAX_RESOLUTION` grid has about
2 pi R^2 faces when it fills the grid (0.93 million at 384), twice that when it is wrinkled; a larger count
could not be met, and would only cost the finest extraction before its warning."""


def check_texture_size(size: int) -> None:
    """Refuse texture sizes that are not a power of two or outside [16, 8192]."""
    if size < MIN_TEXTURE_SIZE or size > MAX_TEXTURE_SIZE or size & (size - 1):
        raise VAError(f"--texture-size must be a power of two from {MIN_TEXTURE_SIZE} to {MAX_TEXTURE_SIZE}, "
                      f"got {size}")


def check_faces(faces: int | None, texture: bool) -> None:
    """Refuse a face count that is not 0 (every face) or at least 4, or one given without a texture."""
    if faces is None:
        return
    if isinstance(faces, bool) or not isinstance(faces, int) or faces < 0 or 0 < faces < 4:
        raise ConfigError(f"--faces must be 0 (keep every face) or at least 4, got {faces}")
    if faces > MAX_FACES:
        raise ConfigError(f"--faces {faces} is more than a mesh here can have (the finest grid, "
                          f"{FACES_MAX_RESOLUTION}^3, gives at most about {MAX_FACES}); ask for at most {MAX_FACES}, "
                          "or 0 to keep every face of the extracted mesh")
    if not texture:
        raise ConfigError("--faces sets the face count of the textured mesh: it needs --texture (va-export mesh), "
                          "and no --no-texture (va-recon, va-batch)")


def faces_option(faces: int | None, max_faces: int | None) -> int | None:
    """``faces``, or ``max_faces`` (its old name, with a note); both given and different: ConfigError."""
    if max_faces is None:
        return faces
    if faces is not None and faces != max_faces:
        raise ConfigError(f"faces={faces} and max_faces={max_faces} disagree; max_faces is the old name of faces")
    warnings.warn("max_faces is now faces; the old name still works for now", stacklevel=3)
    return max_faces


@dataclass(frozen=True)
class ExportConfig(Checked):
    """The mesh and texture options of an export (``va-export mesh``, ``va-recon``, ``va-batch``, the app)."""

    mesh_resolution: int = 128
    """Marching-cubes grid of the mesh (``resolution``^3 cells)."""
    texture: bool = True
    """UV-unwrap the mesh and bake a texture from the input views (GLB and OBJ files)."""
    texture_size: int = 1024
    """Side of the baked texture in texels, a power of two."""
    faces: int | None = None
    """Face count of the textured mesh, by quadric decimation before the unwrap (None: at most
    :data:`~va_plugin.export.atlas.MAX_TEXTURE_FACES`; 0: every face)."""
    fusion: str = "robust"
    """How disagreeing views are fused per texel: ``robust`` consensus or weighted ``mean``."""
    frame: str = "upright"
    """Frame of the GLB and OBJ files: ``upright`` (+Y up, standing on y = 0) or ``training`` (+Z up);
    PLY stays in the training frame."""

    @classmethod
    def of(cls, config: ExportConfig | None = None, **given: Any) -> ExportConfig:
        """``config`` (default: the defaults) with the ``given`` options that are not None, validated: the one
        place where keyword arguments become an export config."""
        if config is not None and not isinstance(config, ExportConfig):
            raise ConfigError(f"export must be an ExportConfig, got {type(config).__name__}")
        names = {item.name for item in fields(cls)}
        unknown = sorted(set(given) - names)
        if unknown:
            raise ConfigError(f"unknown export option {unknown[0]!r}; known: {', '.join(sorted(names))}")
        chosen = {name: value for name, value in given.items() if value is not None}
        return replace(config if config is not None else cls(), **chosen)

    def validate(self, prefix: str = "", resolution_flag: str = "--mesh-resolution") -> None:
        """Refuse options that cannot work, before any marching cubes (one line each); ``resolution_flag``:
        the command's name of :attr:`mesh_resolution` in the messages."""
        check_kinds(mesh_resolution=(self.mesh_resolution, numbers.Integral), texture=(self.texture, bool),
                    texture_size=(self.texture_size, numbers.Integral), fusion=(self.fusion, str),
                    frame=(self.frame, str))
        check_kinds(optional=True, faces=(self.faces, numbers.Integral))
        if self.mesh_resolution < MIN_MESH_RESOLUTION:
            raise ConfigError(f"{resolution_flag} must be at least {MIN_MESH_RESOLUTION}, got {self.mesh_resolution}")
        if self.texture:
            check_texture_size(self.texture_size)
        if self.fusion not in FUSIONS:
            raise ConfigError(f"--fusion must be one of {', '.join(FUSIONS)}, got {self.fusion!r}")
        check_faces(self.faces, self.texture)
        check_frame(self.frame)
        check_mesh_resolution(self.mesh_resolution, resolution_flag)

    @property
    def texture_faces(self) -> int:
        """The face count the textured mesh is decimated to (0: every face)."""
        return MAX_TEXTURE_FACES if self.faces is None else self.faces
