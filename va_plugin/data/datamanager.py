"""The DataManager: loads a scene's splits and hands out training rays."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import torch

from va_plugin.config import InstantiateConfig
from va_plugin.data.bounds import check_distinct_views, check_object_in_bound, warn_object_cut_by_frame
from va_plugin.data.dataparsers.base import DataParserConfig, DataparserOutputs
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.foreground import write_mask_picture
from va_plugin.errors import DataError
from va_plugin.rays import RayBundle

MASK_PICTURE = "masks.png"


@dataclass
class DataManagerConfig(InstantiateConfig):
    """Loads the training and test views and samples training rays."""

    _target: type = field(default_factory=lambda: DataManager)
    dataparser: DataParserConfig = field(default_factory=TransformsDataParserConfig)
    """How to read the scene."""
    rays_per_batch: int = 512
    """Training rays per step."""
    foreground_fraction: float = 0.5
    """Share of each batch drawn from foreground pixels (the rest uniformly from all pixels)."""
    seed: int = 42
    """Seed of the ray sampler's own generator (independent of the model's)."""


class DataManager:
    """Holds the images on the device and draws random training rays with their view indices."""

    def __init__(self, config: DataManagerConfig, device: torch.device | None = None) -> None:
        device = torch.device("cpu") if device is None else device
        if not 0.0 <= config.foreground_fraction <= 1.0:
            raise DataError(f"foreground_fraction must be in [0, 1], got {config.foreground_fraction}")
        if config.rays_per_batch < 1:
            raise DataError(f"rays_per_batch must be positive, got {config.rays_per_batch}")
        self.config = config
        self.device = device
        parser = config.dataparser.setup()
        self.train = parser.get_outputs("train")
        self.test: DataparserOutputs | None = parser.get_outputs("test")
        self.cameras = self.train.cameras.to(device)
        self.images = self.train.images.to(device)
        self.masks = None if self.train.masks is None else self.train.masks.to(device)
        # world-space normal maps [n, H, W, 3] of the training views (zero off the object) when the input
        # has them (Wonder3D): the batches then carry "normal" targets
        normals = self.train.metadata.get("normals")
        self.normals = None if normals is None else normals.to(device=device, dtype=self.images.dtype)
        self.generator = torch.Generator(device="cpu").manual_seed(config.seed)
        self._height, self._width = self.images.shape[1:3]
        self._foreground = self._foreground_pixels()
        check_distinct_views(self.train)
        check_object_in_bound(self.train)
        warn_object_cut_by_frame(self.train)

    @property
    def num_train_views(self) -> int:
        return len(self.train)

    @property
    def scene_radius(self) -> float:
        return self.train.scene_radius

    @property
    def background(self) -> tuple[float, float, float]:
        return self.train.background

    def _foreground_pixels(self) -> torch.Tensor | None:
        """Flat indices ``[m]`` of pixels whose mask is above one half, or None without masks."""
        if self.masks is None:
            return None
        flat = (self.masks.reshape(-1) > 0.5).nonzero().squeeze(-1).cpu()
        if flat.numel() == 0:
            raise DataError("the foreground masks are empty in every view: nothing to reconstruct")
        return flat

    def _sample_flat_indices(self) -> torch.Tensor:
        """Flat pixel indices ``[rays_per_batch]``: ``foreground_fraction`` of them on the mask, the rest anywhere."""
        n = self.config.rays_per_batch
        total = self.images.shape[0] * self._height * self._width
        n_fg = round(n * self.config.foreground_fraction) if self._foreground is not None else 0
        uniform = torch.randint(0, total, (n - n_fg,), generator=self.generator)
        if n_fg == 0:
            return uniform
        pick = torch.randint(0, self._foreground.numel(), (n_fg,), generator=self.generator)
        return torch.cat([self._foreground[pick], uniform])

    def next_train(self, step: int) -> tuple[RayBundle, dict[str, torch.Tensor]]:
        """A random batch of training rays and their targets (``rgb [n, 3]``, ``mask [n, 1]``, and
        ``normal [n, 3]`` when the input has normal maps), with ``pixel [n, 3]`` (view, row, column)."""
        flat = self._sample_flat_indices().to(self.device)
        pixels = self._height * self._width
        views, within = flat // pixels, flat % pixels
        rows, cols = within // self._width, within % self._width
        origins, directions = self.cameras.generate_rays(views, rows, cols)
        batch = {"rgb": self.images[views, rows, cols], "pixel": torch.stack([views, rows, cols], -1)}
        if self.masks is not None:
            batch["mask"] = self.masks[views, rows, cols]
        if self.normals is not None:
            batch["normal"] = self.normals[views, rows, cols]
        return RayBundle(origins, directions, views), batch

    def image_rays(self, outputs: DataparserOutputs, index: int, camera_index: int | None = None
                   ) -> RayBundle:
        """Every ray of one view of ``outputs``, row-major; ``camera_index`` labels them (-1: novel)."""
        cameras = outputs.cameras.to(self.device)
        views, rows, cols = cameras.pixel_grid(index)
        origins, directions = cameras.generate_rays(views, rows, cols)
        label = index if camera_index is None else camera_index
        return RayBundle(origins, directions, torch.full_like(views, label))

    def eval_views(self) -> Iterator[tuple[int, RayBundle, torch.Tensor, torch.Tensor | None]]:
        """The held-out views as (index, rays, image ``[H, W, 3]``, mask or None); novel-view rays."""
        if self.test is None:
            return
        for i in range(len(self.test)):
            mask = None if self.test.masks is None else self.test.masks[i]
            yield i, self.image_rays(self.test, i, camera_index=-1), self.test.images[i], mask

    def save_mask_picture(self, run_dir: Path) -> Path | None:
        """Write ``RUN/masks.png`` (training views above their masks) when the dataparser derived the masks
        from the inputs (generator outputs), so a user can check them; None otherwise."""
        if self.train.masks is None or "mask_source" not in self.train.metadata:
            return None
        return write_mask_picture(Path(run_dir) / MASK_PICTURE, self.train.images.numpy(), self.train.masks.numpy())

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        self.generator.set_state(state["generator"])
