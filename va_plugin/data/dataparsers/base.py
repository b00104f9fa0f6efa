"""What every dataparser returns."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from va_plugin.cameras import Cameras
from va_plugin.config import InstantiateConfig
from va_plugin.data.images import resize
from va_plugin.utils.memory import check_view_memory


@dataclass
class DataparserOutputs:
    """One split of a scene."""

    images: torch.Tensor  # [n, H, W, 3] float in [0, 1], composited on ``background``
    masks: torch.Tensor | None  # [n, H, W, 1] foreground in [0, 1], or None
    cameras: Cameras
    scene_radius: float  # of the bounding sphere at the origin that holds the object
    background: tuple[float, float, float]
    image_paths: list[Path] = field(default_factory=list)  # for messages
    metadata: dict[str, Any] = field(default_factory=dict)  # anything else the source knows

    def __len__(self) -> int:
        return self.images.shape[0]


@dataclass
class DataParserConfig(InstantiateConfig):
    """Common options of every dataparser."""

    data: Path = Path(".")
    """The scene: a folder or file, as the format expects."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """RGB in [0, 1] that transparent pixels are composited on (white by default)."""
    scene_radius: float = 1.0
    """Radius of the bounding sphere at the origin that holds the object (unless the data says otherwise)."""
    image_scale: float = 1.0
    """Resize every image by this factor on load (e.g. 0.5 to train at half resolution)."""

    def input_paths(self) -> dict[str, Path | None]:
        """The options that name input files, by name: what a run reads (its data; generators: their mask
        folder or image too); None where not given."""
        return {"data": self.data}


class DataParser:
    """Reads a scene into :class:`DataparserOutputs` for a split ("train" or "test")."""

    config: DataParserConfig

    def __init__(self, config: DataParserConfig) -> None:
        self.config = config

    def get_outputs(self, split: str = "train") -> DataparserOutputs:
        raise NotImplementedError


def rescale_views(cameras: Cameras, images: np.ndarray, masks: np.ndarray | None, factor: float
                  ) -> tuple[Cameras, np.ndarray, np.ndarray | None]:
    """Cameras, images ``[n, H, W, 3]`` and masks ``[n, H, W, 1]`` resized by ``factor`` (1: unchanged)."""
    if factor == 1.0:
        return cameras, images, masks
    check_view_memory(len(images), int(cameras.width), int(cameras.height), factor)
    cameras = cameras.scaled(factor)
    images = np.stack([resize(im, cameras.width, cameras.height) for im in images])
    if masks is not None:
        masks = np.stack([resize(m, cameras.width, cameras.height) for m in masks])
    return cameras, images, masks
