"""What every generator-output dataparser shares: masks, the silhouette check and normalisation.

The one reader (:class:`~va_plugin.data.dataparsers.rigged.RigDataParser`) reads a generator's file
layout and gives its views the cameras of its rig file (:mod:`va_plugin.data.rigfile`); this base finds a
mask per view (the user's masks, else alpha, else a color key: :mod:`va_plugin.data.foreground`) and
composites the views on the background. With ``normalize = "silhouettes"`` the cameras are moved and
scaled so the masks' visual hull fills the unit box; the hull's per-view silhouette IoU is kept in the
metadata as a check of the rig.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from va_plugin.cameras import Cameras
from va_plugin.data.dataparsers.base import DataParser, DataParserConfig, DataparserOutputs, rescale_views
from va_plugin.data.foreground import ColorKey, check_masks, color_key_mask, composite, mask_from_image
from va_plugin.data.images import read_image, split_alpha
from va_plugin.data.rigfile import IMAGE_SUFFIXES
from va_plugin.data.visual_hull import normalise_cameras, unit_box_transform, visual_hull
from va_plugin.errors import ConfigError, DataError

NORMALIZE_MODES = ("rig", "silhouettes")
LOW_SILHOUETTE_IOU = 0.8  # below this (mean, or any one view) the rig does not explain the views


def image_files(folder: Path) -> list[Path]:
    """The image files directly in ``folder``, sorted by name."""
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def split_strip(image: np.ndarray, count: int, where: str, layout: str) -> list[np.ndarray]:
    """``count`` square tiles side by side -> list of ``[H, H, C]``; a clear error for any other size."""
    height, width = image.shape[:2]
    if width != count * height:
        raise DataError(f"{where} is {height} high x {width} wide; expected {layout}")
    return [image[:, k * height:(k + 1) * height] for k in range(count)]


def split_grid(image: np.ndarray, rows: int, columns: int, where: str, layout: str) -> list[np.ndarray]:
    """A grid of ``rows x columns`` square tiles, row-major -> list of ``[t, t, C]``."""
    height, width = image.shape[:2]
    tile = width // columns
    if width != columns * tile or height != rows * tile or tile == 0:
        raise DataError(f"{where} is {width} wide x {height} high; expected {layout}")
    return [image[r * tile:(r + 1) * tile, c * tile:(c + 1) * tile] for r in range(rows) for c in range(columns)]


@dataclass
class GeneratorDataParserConfig(DataParserConfig):
    """Options shared by the generator-output dataparsers."""

    scene_radius: float = 0.9
    """Radius of the bounding sphere; the object is brought into the unit box, whose corners are at 0.87."""
    masks: Path | None = None
    """Masks that override the color key and any alpha: a folder with one image per view (view order), or
    one image with the same layout as the input. White (or opaque) is the object."""
    color_key: ColorKey = field(default_factory=ColorKey)
    """How the background is keyed out of views without alpha."""
    normalize: str = "rig"
    """"rig": trust the generator's documented object scale; "silhouettes": centre and scale the visual
    hull of the masks into the unit box."""
    hull_resolution: int = 64
    """Voxels along the longest side of the visual hull (for normalisation and the silhouette check)."""

    def validate(self, prefix: str = "") -> None:
        """A known ``normalize`` mode."""
        if self.normalize not in NORMALIZE_MODES:
            raise ConfigError(f"unknown {prefix}normalize mode {self.normalize!r}; use one of: "
                              f"{', '.join(NORMALIZE_MODES)}")

    def input_paths(self) -> dict[str, Path | None]:
        """The data and the mask folder or image."""
        return {**super().input_paths(), "masks": self.masks}


@dataclass
class _Views:
    """Every view of a generator output, before the split into training and held-out views."""

    images: np.ndarray  # [n, H, W, 3]
    masks: np.ndarray  # [n, H, W, 1]
    cameras: Cameras
    paths: list[Path]
    metadata: dict[str, Any]


class GeneratorDataParser(DataParser):
    """Shared reading, masking and normalisation; subclasses give the layout and the rig."""

    config: GeneratorDataParserConfig
    format_name = "generator"
    layout = ""

    def __init__(self, config: GeneratorDataParserConfig) -> None:
        super().__init__(config)
        self._views: _Views | None = None

    # -- what a generator defines ---------------------------------------------------------------------
    def read_tiles(self) -> tuple[list[np.ndarray], list[str], list[Path]]:
        """The views as ``[t, t, 3|4]`` arrays, a name for each (for messages) and the file each came from."""
        raise NotImplementedError

    def split_image(self, image: np.ndarray, where: str) -> list[np.ndarray]:
        """Tiles of one image in this generator's layout (for mask images given in that layout)."""
        raise DataError(f"{self.format_name} masks must be a folder with one image per view")

    def rig(self, tile_size: int) -> Cameras:
        raise NotImplementedError

    def train_ids(self, count: int) -> list[int]:
        return list(range(count))

    def view_names(self) -> Sequence[str] | None:
        """Names that identify each view in a file name, when the generator names its files by view."""
        return None

    def extra_metadata(self, cameras: Cameras, masks: np.ndarray) -> dict[str, Any]:
        return {}

    # -- shared -------------------------------------------------------------------------------------
    def _user_masks(self, count: int, size: int) -> list[np.ndarray]:
        path = Path(self.config.masks)
        if path.is_file():
            tiles = self.split_image(read_image(path), str(path))
            files = [path] * len(tiles)
        elif path.is_dir():
            files = self._mask_files(path, count)
            tiles = [read_image(f) for f in files]
        else:
            raise DataError(f"mask folder or image not found: {path}")
        if len(tiles) != count:
            raise DataError(f"{path} gives {len(tiles)} masks; the input has {count} views")
        masks = []
        for tile, file in zip(tiles, files):
            if tile.shape[:2] != (size, size):
                raise DataError(f"mask {file} is {tile.shape[1]}x{tile.shape[0]}; the views are {size}x{size}")
            masks.append(mask_from_image(tile))
        return masks

    def _mask_files(self, folder: Path, count: int) -> list[Path]:
        files = image_files(folder)
        names = self.view_names()
        if names is not None:
            by_view: dict[str, list[Path]] = {view: [] for view in names}
            for file in files:
                # the longest view name the file name ends with ("front_right" before "right")
                ends = [v for v in names if re.search(rf"(^|_){v}$", file.stem)]
                if ends:
                    by_view[max(ends, key=len)].append(file)
            if all(len(found) == 1 for found in by_view.values()):
                return [by_view[view][0] for view in names]
        if len(files) != count:
            order = f" named by view ({', '.join(names)})" if names else " in view order (sorted by name)"
            raise DataError(f"mask folder {folder} holds {len(files)} images; expected {count}, one per view{order}")
        return files

    def _load(self) -> _Views:
        if self._views is not None:
            return self._views
        tiles, names, paths = self.read_tiles()
        size = tiles[0].shape[0]
        key = self.config.color_key
        background = self.config.background
        if self.config.masks is not None:
            masks = self._user_masks(len(tiles), size)
            check_masks(masks, [f"mask of {n}" for n in names], key)
            images = [composite(split_alpha(t, background)[0], m, background) for t, m in zip(tiles, masks)]
            source = f"mask files ({self.config.masks})"
        elif all(t.shape[2] == 4 for t in tiles) and not all(opaque(t) for t in tiles):
            pairs = [split_alpha(t, background) for t in tiles]
            images, masks = [p[0] for p in pairs], [p[1] for p in pairs]
            check_masks(masks, [f"alpha of {n}" for n in names], key)
            source = "alpha channel"
        else:
            if all(t.shape[2] == 4 for t in tiles):
                warnings.warn(f"{self.config.data}: the alpha channel is opaque everywhere, so it holds no "
                              "mask; the background is keyed out by its color instead (or pass --masks)", stacklevel=2)
            rgb = [t[:, :, :3] for t in tiles]
            masks = [color_key_mask(im, key, where=n) for im, n in zip(rgb, names)]
            images = [composite(im, m, background) for im, m in zip(rgb, masks)]
            source = "color key"
        masks_np = np.stack(masks).astype(np.float32)
        cameras = self.rig(size)
        cameras, hull_info = self._place(cameras, masks_np)
        metadata = {"format": self.format_name, "source": str(self.config.data), "mask_source": source,
                    "view_names": list(names), **hull_info}
        metadata.update(self.extra_metadata(cameras, masks_np))
        self._views = _Views(np.stack(images).astype(np.float32), masks_np, cameras, paths, metadata)
        return self._views

    def _place(self, cameras: Cameras, masks: np.ndarray) -> tuple[Cameras, dict[str, Any]]:
        """Check the rig against the masks' visual hull and, with ``normalize = "silhouettes"``, move the
        hull's box to the unit box at the origin."""
        mode = self.config.normalize
        if mode not in NORMALIZE_MODES:
            raise ConfigError(f"unknown normalize mode {mode!r}; use one of: {', '.join(NORMALIZE_MODES)}")
        silhouettes = torch.from_numpy(masks[..., 0] > 0.5)
        hull = visual_hull(cameras, silhouettes, self.config.hull_resolution)
        if hull.points.numel() == 0:
            raise DataError(f"{self.config.data}: the {len(cameras)} views' silhouettes share no volume under the "
                            f"{self.format_name} rig; is the format (--data-format) or rig option right?")
        centre, scale = torch.zeros(3), 1.0
        if mode == "silhouettes":
            centre, scale = unit_box_transform(*hull.bounds)
            cameras, hull = normalise_cameras(cameras, centre, scale), hull.moved(centre, scale)
        iou = hull.silhouette_iou
        worst = min(range(len(iou)), key=iou.__getitem__)
        if sum(iou) / len(iou) < LOW_SILHOUETTE_IOU or iou[worst] < LOW_SILHOUETTE_IOU:
            warnings.warn(f"{self.config.data}: the masks agree poorly with the {self.format_name} rig (mean "
                          f"silhouette IoU {sum(iou) / len(iou):.2f}, view {worst} {iou[worst]:.2f}): the views "
                          "may not fit the rig; check the format and rig options and the mask picture in the "
                          "run folder", stacklevel=2)
        lower, upper = hull.bounds
        info = {"normalize": mode, "hull_bounds": [lower.tolist(), upper.tolist()],
                "silhouette_iou": [round(v, 4) for v in iou],
                # the rig's world -> the training frame: x' = (x - centre) * scale
                "rig_to_training": {"centre": [float(c) for c in centre], "scale": float(scale)}}
        return cameras, info

    def get_outputs(self, split: str = "train") -> DataparserOutputs | None:
        views = self._load()
        count = len(views.paths)
        train = self.train_ids(count)
        ids = train if split == "train" else [i for i in range(count) if i not in train]
        if not ids:
            return None
        cameras, images, masks = rescale_views(views.cameras.subset(ids), views.images[ids], views.masks[ids],
                                               self.config.image_scale)
        metadata = dict(views.metadata, view_ids=ids)
        return DataparserOutputs(
            images=torch.from_numpy(np.ascontiguousarray(images)).float(),
            masks=torch.from_numpy(np.ascontiguousarray(masks)).float(),
            cameras=cameras, scene_radius=float(self.config.scene_radius),
            background=tuple(self.config.background), image_paths=[views.paths[i] for i in ids], metadata=metadata)


def opaque(tile: np.ndarray) -> bool:
    """Whether an RGBA tile's alpha is 1 everywhere (an image saved with alpha that carries no mask)."""
    return tile.shape[2] == 4 and float(tile[:, :, 3].min()) >= 1.0 - 0.5 / 255


def read_normal_maps(paths: Sequence[Path], cameras: Cameras, masks: np.ndarray, normal_frame: str,
                     turns: int = 0) -> dict[str, Any]:
    """World-space normal maps ``[n, H, W, 3]`` (zero outside their alpha, or the view's mask) from images
    that store ``(n + 1) / 2`` in OpenGL camera axes of the first camera (``normal_frame`` "front") or of
    each view's own ("view"); ``turns``: quarter turns that make each image upright, as its view."""
    normals = []
    for k, path in enumerate(paths):
        image = np.ascontiguousarray(np.rot90(read_image(path), turns))
        if image.shape[:2] != masks.shape[1:3]:
            raise DataError(f"{path} is {image.shape[1]}x{image.shape[0]}; the views are "
                            f"{masks.shape[2]}x{masks.shape[1]}")
        # stored as (n + 1) / 2 in OpenGL camera axes (x right, y up, z towards the viewer)
        n_gl = torch.from_numpy(image[:, :, :3] * 2.0 - 1.0)
        n_cv = n_gl * torch.tensor([1.0, -1.0, -1.0])
        frame = 0 if normal_frame == "front" else k
        world = torch.nn.functional.normalize(n_cv @ cameras.c2w[frame, :, :3].T, dim=-1)
        alpha = torch.from_numpy(np.ascontiguousarray(image[:, :, 3:] if image.shape[2] == 4 else masks[k]))
        normals.append(world * (alpha > 0.5))
    return {"normals": torch.stack(normals), "normal_paths": [str(p) for p in paths]}
