"""Where each training view disagrees with the shared field of a view-adaptive run: per view, its branch
render against the canonical render (the texture bake weights a view down there; the diagnostics draw it)."""

from __future__ import annotations

import cv2
import numpy as np
import torch

from va_plugin.export.render import render_view
from va_plugin.utils.progress import progress_bar


@torch.no_grad()
def inconsistency_maps(pipeline, scale: float = 0.5, progress: bool = False) -> list[dict[str, np.ndarray]]:
    """Per training view: its (resized) input, its branch render, its canonical render and the map
    ``|branch - canonical|`` (mean over RGB), all at ``scale`` of the input resolution."""
    dm = pipeline.datamanager
    model = pipeline.model
    field = model.field
    cameras = dm.cameras.scaled(scale) if scale != 1.0 else dm.cameras
    was_training = model.training
    model.eval()
    out = []
    try:
        field.also_canonical = True  # one pass per view renders both images
        for view in progress_bar(range(dm.num_train_views), desc="inconsistency maps", disable=not progress):
            own, canonical = render_view(model, cameras, view, as_view=view, keys=("rgb", "rgb_canonical"))
            target = cv2.resize(dm.images[view].cpu().numpy(), (cameras.width, cameras.height),
                                interpolation=cv2.INTER_AREA)
            out.append({"input": target, "own": own, "canonical": canonical,
                        "map": np.abs(own - canonical).mean(-1)})
    finally:
        model.train(was_training)
        field.also_canonical = False
    return out
