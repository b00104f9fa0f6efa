"""The DataManager: loads a scene's splits and hands out training rays."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, Optional, Tuple, Type

import torch

from va_plugin.config import InstantiateConfig
from va_plugin.data.bounds import check_object_in_bound, warn_object_cut_by_frame
from va_plugin.data.dataparsers.base import DataParserConfig, DataparserOutputs
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.foreground import write_mask_picture
from va_plugin.errors import DataError
from va_plugin.model_components.view_warp import gaussian_blurred, sample_bilinear, sample_bilinear_blur_slope
from va_plugin.rays import RayBundle

MASK_PICTURE = "masks.png"
ERROR_SOURCES = ("rgb", "mask")


@dataclass
class DataManagerConfig(InstantiateConfig):
    """Loads the training and test views and samples training rays."""

    _target: Type = field(default_factory=lambda: DataManager)
    dataparser: DataParserConfig = field(default_factory=TransformsDataParserConfig)
    """How to read the scene."""
    rays_per_batch: int = 512
    """Training rays per step."""
    foreground_fraction: float = 0.5
    """Share of each batch drawn from foreground pixels (the rest uniformly from all pixels)."""
    seed: int = 42
    """Seed of the ray sampler's own generator (independent of the model's)."""
    error_sampling_fraction: float = 0.0
    """Share of each batch drawn in proportion to each pixel's error when it was last drawn (0: off;
    the rest of the batch as ``foreground_fraction`` says). Pixels never drawn count as the mean error of
    those that were, and a tenth of the mean is added to every pixel, so none is starved."""
    error_sampling_source: str = "rgb"
    """Which error guides that share: ``rgb`` (the squared colour error of the composited render) or
    ``mask`` (the squared error of the opacity against the mask: the outline only; needs masks)."""
    pixel_jitter: bool = False
    """Send each training ray through a uniformly random point of its pixel instead of the pixel's
    centre (the target stays the pixel's value): the field then learns each pixel as the average over
    its area, as a camera records it, and the fine grid cells between pixel centres get a say."""


class DataManager:
    """Holds the images on the device and draws random training rays with their view indices."""

    def __init__(self, config: DataManagerConfig, device: torch.device = torch.device("cpu")) -> None:
        if not 0.0 <= config.foreground_fraction <= 1.0:
            raise DataError(f"foreground_fraction must be in [0, 1], got {config.foreground_fraction}")
        if not 0.0 <= config.error_sampling_fraction <= 1.0:
            raise DataError(f"error_sampling_fraction must be in [0, 1], got {config.error_sampling_fraction}")
        if config.error_sampling_source not in ERROR_SOURCES:
            raise DataError(f"error_sampling_source must be one of {', '.join(ERROR_SOURCES)}, "
                            f"got {config.error_sampling_source!r}")
        if config.rays_per_batch < 1:
            raise DataError(f"rays_per_batch must be positive, got {config.rays_per_batch}")
        self.config = config
        self.device = device
        parser = config.dataparser.setup()
        self.train = parser.get_outputs("train")
        self.test: Optional[DataparserOutputs] = parser.get_outputs("test")
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
        self._blurred: Dict[Tuple[str, float], torch.Tensor] = {}  # blurred inputs for view_warp.gradient_blur
        # each pixel's error (error_sampling_source) when last drawn (NaN: never drawn), for error_sampling_fraction
        self.pixel_errors: Optional[torch.Tensor] = None
        if config.error_sampling_fraction > 0:
            self.pixel_errors = torch.full((self.images.shape[0] * self._height * self._width,), float("nan"))
        if self.pixel_errors is not None and config.error_sampling_source == "mask" and self.masks is None:
            raise DataError("error_sampling_source=mask needs masks, and this input has none "
                            "(give --masks, or use error_sampling_source=rgb)")
        check_object_in_bound(self.train)
        warn_object_cut_by_frame(self.train)

    @property
    def num_train_views(self) -> int:
        return len(self.train)

    @property
    def scene_radius(self) -> float:
        return self.train.scene_radius

    @property
    def background(self) -> Tuple[float, float, float]:
        return self.train.background

    def _foreground_pixels(self) -> Optional[torch.Tensor]:
        """Flat indices ``[m]`` of pixels whose mask is above one half, or None without masks."""
        if self.masks is None:
            return None
        flat = (self.masks.reshape(-1) > 0.5).nonzero().squeeze(-1).cpu()
        if flat.numel() == 0:
            raise DataError("the foreground masks are empty in every view: nothing to reconstruct")
        return flat

    @property
    def error_guided(self) -> bool:
        """Whether part of each batch follows the pixels' errors (see :meth:`record_batch_errors`)."""
        return self.pixel_errors is not None

    def record_batch_errors(self, outputs: Dict[str, torch.Tensor], batch: Dict[str, torch.Tensor]) -> None:
        """Record the error that ``error_sampling_source`` names for a rendered training batch."""
        if self.pixel_errors is None:
            return
        if self.config.error_sampling_source == "mask":
            errors = ((outputs["accumulation"].detach() - batch["mask"]) ** 2).sum(-1)
        else:
            errors = ((outputs["rgb"].detach() - batch["rgb"]) ** 2).sum(-1)
        self.record_errors(batch["pixel"], errors)

    def record_errors(self, pixel: torch.Tensor, errors: torch.Tensor) -> None:
        """Remember the error ``errors [n]`` of the batch's pixels ``pixel [n, 3]`` (view, row, column)
        for the next batches' error-guided share; a no-op when that share is off."""
        if self.pixel_errors is None:
            return
        views, rows, cols = pixel.detach().cpu().unbind(-1)
        flat = (views * self._height + rows) * self._width + cols
        self.pixel_errors[flat] = errors.detach().float().cpu().nan_to_num(0.0, 0.0, 0.0)

    def _error_guided_indices(self, n: int) -> torch.Tensor:
        errors = self.pixel_errors
        seen = ~torch.isnan(errors)
        mean = float(errors[seen].mean()) if bool(seen.any()) else 1.0
        weights = torch.where(seen, errors, torch.full_like(errors, mean)) + (0.1 * mean + 1e-12)
        return torch.multinomial(weights, n, replacement=True, generator=self.generator)

    def _sample_flat_indices(self) -> torch.Tensor:
        n = self.config.rays_per_batch
        guided = None
        if self.pixel_errors is not None:
            n_guided = int(round(n * self.config.error_sampling_fraction))
            guided, n = self._error_guided_indices(n_guided), n - n_guided
        flat = self._plain_indices(n)
        return flat if guided is None else torch.cat([guided, flat])

    def _plain_indices(self, n: int) -> torch.Tensor:
        total = self.images.shape[0] * self._height * self._width
        n_fg = int(round(n * self.config.foreground_fraction)) if self._foreground is not None else 0
        uniform = torch.randint(0, total, (n - n_fg,), generator=self.generator)
        if n_fg == 0:
            return uniform
        pick = torch.randint(0, self._foreground.numel(), (n_fg,), generator=self.generator)
        return torch.cat([self._foreground[pick], uniform])

    def next_train(self, step: int) -> Tuple[RayBundle, Dict[str, torch.Tensor]]:
        """A random batch of training rays and their targets (``rgb [n, 3]``, ``mask [n, 1]``, and
        ``normal [n, 3]`` when the input has normal maps), with ``pixel [n, 3]`` (view, row, column)."""
        flat = self._sample_flat_indices().to(self.device)
        pixels = self._height * self._width
        views, within = flat // pixels, flat % pixels
        rows, cols = within // self._width, within % self._width
        ray_rows, ray_cols = rows, cols
        if self.config.pixel_jitter:  # offsets from the sampler's own generator: resume stays exact
            offsets = torch.rand((2, rows.shape[0]), generator=self.generator).to(self.device) - 0.5
            ray_rows, ray_cols = rows + offsets[0], cols + offsets[1]
        origins, directions = self.cameras.generate_rays(views, ray_rows, ray_cols)
        batch = {"rgb": self.images[views, rows, cols], "pixel": torch.stack([views, rows, cols], -1)}
        if self.masks is not None:
            batch["mask"] = self.masks[views, rows, cols]
        if self.normals is not None:
            batch["normal"] = self.normals[views, rows, cols]
        return RayBundle(origins, directions, views), batch

    def warped_targets(self, batch: Dict[str, torch.Tensor], warp) -> Dict[str, torch.Tensor]:
        """``batch`` with its targets read at ``pixel + shift`` instead of at the pixels themselves; ``warp``
        (a :class:`ViewWarp`) gives the shifts (bilinear reading, differentiable in them)."""
        views, rows, cols = batch["pixel"].unbind(-1)
        shifts = warp.shifts(views, rows, cols, self._height, self._width)  # columns, rows; pixels
        rows_f, cols_f = rows.to(shifts.dtype) + shifts[:, 1], cols.to(shifts.dtype) + shifts[:, 0]
        sigma = warp.config.gradient_blur
        out = dict(batch)
        for key, images in (("rgb", self.images), ("mask", self.masks), ("normal", self.normals)):
            if images is None:
                continue
            if sigma > 0:  # the slope from a blurred copy (made once per sigma), the values sharp
                cache = (key, sigma)
                if cache not in self._blurred:
                    self._blurred[cache] = gaussian_blurred(images, sigma)
                out[key] = sample_bilinear_blur_slope(images, self._blurred[cache], views, rows_f, cols_f)
            else:
                out[key] = sample_bilinear(images, views, rows_f, cols_f)
        return out

    def image_rays(self, outputs: DataparserOutputs, index: int, camera_index: Optional[int] = None
                   ) -> RayBundle:
        """Every ray of one view of ``outputs``, row-major; ``camera_index`` labels them (-1: novel)."""
        cameras = outputs.cameras.to(self.device)
        views, rows, cols = cameras.pixel_grid(index)
        origins, directions = cameras.generate_rays(views, rows, cols)
        label = index if camera_index is None else camera_index
        return RayBundle(origins, directions, torch.full_like(views, label))

    def eval_views(self) -> Iterator[Tuple[int, RayBundle, torch.Tensor, Optional[torch.Tensor]]]:
        """The held-out views as (index, rays, image ``[H, W, 3]``, mask or None); novel-view rays."""
        if self.test is None:
            return
        for i in range(len(self.test)):
            mask = None if self.test.masks is None else self.test.masks[i]
            yield i, self.image_rays(self.test, i, camera_index=-1), self.test.images[i], mask

    def save_mask_picture(self, run_dir: Path) -> Optional[Path]:
        """Write ``RUN/masks.png`` (training views above their masks) when the dataparser derived the masks
        from the inputs (generator outputs), so a user can check them; None otherwise."""
        if self.train.masks is None or "mask_source" not in self.train.metadata:
            return None
        return write_mask_picture(Path(run_dir) / MASK_PICTURE, self.train.images.numpy(), self.train.masks.numpy())

    def state_dict(self) -> Dict[str, torch.Tensor]:
        state = {"generator": self.generator.get_state()}
        if self.pixel_errors is not None:
            state["pixel_errors"] = self.pixel_errors.clone()
        return state

    def load_state_dict(self, state: Dict[str, torch.Tensor]) -> None:
        self.generator.set_state(state["generator"])
        if self.pixel_errors is not None and "pixel_errors" in state:
            self.pixel_errors.copy_(state["pixel_errors"])
