"""Our DataManager behind nerfstudio's ``DataManager``: the same training rays, drawn by the same seeded
sampler, as ``va-train`` draws them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from nerfstudio.cameras.cameras import Cameras as NSCameras
from nerfstudio.configs.dataparser_configs import AnnotatedDataParserUnion
from nerfstudio.data.datamanagers.base_datamanager import DataManager, DataManagerConfig

from va_plugin.data.datamanager import DataManager as VADataManager
from va_plugin.data.datamanager import DataManagerConfig as VADataManagerConfig
from va_plugin.errors import ConfigError
from va_plugin.nerfstudio.dataparser import (
    VAGeneratorDataParser,
    VAGeneratorDataParserConfig,
    scene_box,
    to_nerfstudio_cameras,
)
from va_plugin.rays import RayBundle


class TrainingViews:
    """The training views as the viewer reads a dataset: ``cameras`` (nerfstudio's), ``len`` and
    ``[i]["image"]`` ``[H, W, 3]``."""

    def __init__(self, images: torch.Tensor, cameras: NSCameras, radius: float) -> None:
        self.images, self.cameras, self.scene_box = images, cameras, scene_box(radius)
        self.metadata: dict[str, Any] = {}

    def __len__(self) -> int:
        return self.images.shape[0]

    def __getitem__(self, index: int) -> dict[str, Any]:
        return {"image_idx": index, "image": self.images[index]}


@dataclass
class VAGeneratorDataManagerConfig(DataManagerConfig):
    """va-plugin's ray sampler over the views of a ``va-generator`` input."""

    _target: type = field(default_factory=lambda: VAGeneratorDataManager)
    dataparser: AnnotatedDataParserUnion = field(default_factory=VAGeneratorDataParserConfig)
    """How to read the input (the va methods read it with va-generator)."""
    # our DataManagerConfig's defaults, so that both trainers draw the same rays unless told otherwise
    rays_per_batch: int = VADataManagerConfig.rays_per_batch
    """Training rays per step."""
    foreground_fraction: float = VADataManagerConfig.foreground_fraction
    """Share of each batch drawn from foreground pixels (the rest uniformly from all pixels)."""
    seed: int = VADataManagerConfig.seed
    """Seed of the ray sampler's own generator (independent of the model's)."""


class VAGeneratorDataManager(DataManager):
    """Holds our DataManager (``va``) and hands out its batches; no evaluation batches (``eval_dataset``
    is None, so nerfstudio's trainer runs no eval iterations)."""

    config: VAGeneratorDataManagerConfig

    def __init__(self, config: VAGeneratorDataManagerConfig, device: torch.device | str = "cpu",
                 test_mode: str = "val", world_size: int = 1, local_rank: int = 0, **kwargs: Any) -> None:
        self.config, self.device, self.test_mode = config, torch.device(device), test_mode
        if config.data is not None:  # ns-train's --data, before the dataparser subcommand
            config.dataparser.data = Path(config.data)
        parser = config.dataparser.setup()
        if not isinstance(parser, VAGeneratorDataParser):
            raise ConfigError(f"the va methods read their input with the va-generator dataparser, not "
                              f"{type(config.dataparser).__name__}")
        self.va_config = VADataManagerConfig(dataparser=parser.va_config(), rays_per_batch=config.rays_per_batch,
                                             foreground_fraction=config.foreground_fraction, seed=config.seed)
        self.va = VADataManager(self.va_config, device=self.device)
        self.train_dataset = TrainingViews(self.va.train.images, to_nerfstudio_cameras(self.va.train.cameras),
                                           self.va.scene_radius)
        self.eval_dataset = None
        super().__init__()

    def setup_train(self) -> None:
        """Nothing to set up: ``va`` samples the rays."""

    def next_train(self, step: int) -> tuple[RayBundle, dict[str, torch.Tensor]]:
        self.train_count += 1
        return self.va.next_train(step)

    def next_eval(self, step: int):
        raise ConfigError("the va methods evaluate with va-eval --load-dir RUN, not with eval batches")

    def next_eval_image(self, step: int):
        raise ConfigError("the va methods evaluate with va-eval --load-dir RUN, not with eval images")

    def get_train_rays_per_batch(self) -> int:
        return self.config.rays_per_batch

    def get_eval_rays_per_batch(self) -> int:
        return self.config.rays_per_batch

    def get_datapath(self) -> Path:
        return Path(self.config.dataparser.data)

    def get_param_groups(self) -> dict[str, list[torch.nn.Parameter]]:
        return {}
