"""The ``va-generator`` dataparser: our readers of generator outputs behind nerfstudio's ``DataParser``.

``ns-train va-neus va-generator --data strip.png`` reads a SyncDreamer strip, a Zero123++ grid, a Wonder3D
folder or a transforms.json scene with the same parser ``va-train`` picks for that input
(:func:`va_plugin.data.dataparsers.resolve_dataparser`). The va methods take the parsed views straight from
:meth:`VAGeneratorDataParser.va_outputs`; nerfstudio's own methods get the usual ``DataparserOutputs``,
whose image files are the parsed views written as RGBA PNGs (alpha: the foreground mask) into a cache
folder keyed by the input and the options.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras as NSCameras
from nerfstudio.cameras.cameras import CameraType
from nerfstudio.data.dataparsers.base_dataparser import DataParser, DataParserConfig, DataparserOutputs
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.plugins.registry_dataparser import DataParserSpecification

from va_plugin.cameras import ORTHOGRAPHIC, Cameras, opengl_to_opencv
from va_plugin.data.dataparsers import FORMATS, resolve_dataparser
from va_plugin.data.dataparsers import DataParserConfig as VADataParserConfig
from va_plugin.data.dataparsers.base import DataparserOutputs as VAOutputs
from va_plugin.data.images import write_image
from va_plugin.errors import DataError

DataFormat = Literal["auto", "transforms", "syncdreamer", "zero123pp", "wonder3d"]
CACHE_DIR = Path.home() / ".cache" / "va-plugin" / "nerfstudio-views"


@dataclass
class VAGeneratorDataParserConfig(DataParserConfig):
    """Multi-view generator outputs read by va-plugin's parsers."""

    _target: type = field(default_factory=lambda: VAGeneratorDataParser)
    data: Path = Path()
    """The input: a SyncDreamer strip, a Zero123++ grid, a Wonder3D folder or a transforms.json scene."""
    data_format: DataFormat = "auto"
    """The input's format; auto: told from the input."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB in [0, 1] that transparent pixels are composited on."""
    scene_radius: float = 1.0
    """Radius of the bounding sphere at the origin that holds the object."""
    image_scale: float = 1.0
    """Resize every view by this factor on load."""
    cache_dir: Path = CACHE_DIR
    """Where the parsed views are written as PNG files for nerfstudio's own methods (the va methods read
    them from memory)."""


def to_nerfstudio_cameras(cameras: Cameras) -> NSCameras:
    """Our cameras (OpenCV axes, our pixel offset) as nerfstudio's (OpenGL axes, pixel centres at +0.5)."""
    shift = 0.5 - cameras.pixel_offset
    kind = CameraType.ORTHOPHOTO if cameras.camera_type == ORTHOGRAPHIC else CameraType.PERSPECTIVE
    return NSCameras(camera_to_worlds=opengl_to_opencv(cameras.c2w.cpu()), fx=cameras.fx.cpu()[:, None],
                     fy=cameras.fy.cpu()[:, None], cx=(cameras.cx.cpu() + shift)[:, None],
                     cy=(cameras.cy.cpu() + shift)[:, None], width=cameras.width, height=cameras.height,
                     camera_type=kind)


def scene_box(radius: float) -> SceneBox:
    return SceneBox(aabb=torch.tensor([[-radius] * 3, [radius] * 3], dtype=torch.float32))


class VAGeneratorDataParser(DataParser):
    """Parses the input once per split with our parser for its format."""

    config: VAGeneratorDataParserConfig

    def __init__(self, config: VAGeneratorDataParserConfig) -> None:
        super().__init__(config)
        self._outputs: dict[str, VAOutputs | None] = {}

    def va_config(self) -> VADataParserConfig:
        """Our parser's config for the input, with this config's common options."""
        base = VADataParserConfig(background=tuple(self.config.background), scene_radius=self.config.scene_radius,
                                  image_scale=self.config.image_scale)
        if self.config.data_format not in ("auto", *FORMATS):
            raise DataError(f"unknown data format {self.config.data_format!r}; known: auto, {', '.join(FORMATS)}")
        return resolve_dataparser(Path(self.config.data).expanduser().resolve(), self.config.data_format, base)

    def va_outputs(self, split: str = "train") -> VAOutputs | None:
        """Our parser's views of ``split`` (None: the input holds no such split)."""
        if split not in self._outputs:
            self._outputs[split] = self.va_config().setup().get_outputs(split)
        return self._outputs[split]

    def _generate_dataparser_outputs(self, split: str = "train", **kwargs) -> DataparserOutputs:
        outputs = self.va_outputs(split if split == "train" else "test") or self.va_outputs("train")
        assert outputs is not None
        return DataparserOutputs(image_filenames=self._view_files(outputs, split),
                                 cameras=to_nerfstudio_cameras(outputs.cameras),
                                 alpha_color=torch.tensor(outputs.background, dtype=torch.float32),
                                 scene_box=scene_box(outputs.scene_radius), metadata={})

    def _view_files(self, outputs: VAOutputs, split: str) -> list[Path]:
        """The views as RGBA PNG files (written once per input and options)."""
        data = Path(self.config.data).expanduser().resolve()
        stamp = f"{data}|{data.stat().st_mtime_ns}|{self.config}|{split}".encode()
        folder = Path(self.config.cache_dir).expanduser() / f"{data.stem}-{hashlib.sha1(stamp).hexdigest()[:12]}"
        files = [folder / f"view_{i:03d}.png" for i in range(len(outputs))]
        if all(f.is_file() for f in files):
            return files
        folder.mkdir(parents=True, exist_ok=True)
        masks = outputs.masks if outputs.masks is not None else torch.ones_like(outputs.images[..., :1])
        for path, image, mask in zip(files, outputs.images.numpy(), masks.numpy(), strict=True):
            write_image(path, np.concatenate([image, mask], axis=-1))
        return files


va_generator = DataParserSpecification(
    config=VAGeneratorDataParserConfig(),
    description="va-plugin's readers: SyncDreamer strip, Zero123++ grid, Wonder3D folder, transforms.json")
