"""PSNR and SSIM: hand-checkable identities, and SSIM against scikit-image."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.metrics import structural_similarity

from va_plugin.eval import psnr, ssim
from va_plugin.eval.image import PSNR_CAP_DB


def _pair(shape, seed, noise=0.1):
    rng = np.random.default_rng(seed)
    a = rng.random(shape)
    b = np.clip(a + noise * rng.standard_normal(shape), 0.0, 1.0)
    return a, b


def _skimage_ssim(a, b):
    return structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1
    )


def test_psnr_identical_images_hit_the_documented_cap():
    img = np.random.default_rng(0).random((16, 16, 3))
    assert psnr(img, img) == pytest.approx(PSNR_CAP_DB)
    assert PSNR_CAP_DB == 100.0


def test_psnr_constant_offset_is_20db():
    gt = np.full((8, 8, 3), 0.5)
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-4)
    gt8 = torch.tensor(gt * 255.0)
    assert psnr(gt8 + 25.5, gt8, max_val=255.0) == pytest.approx(20.0, abs=1e-4)


def test_psnr_matches_hand_computed_mse_and_is_symmetric():
    a, b = _pair((20, 24, 3), seed=1)
    expected = 10.0 * math.log10(1.0 / np.mean((a - b) ** 2))
    assert psnr(a, b) == pytest.approx(expected, abs=1e-4)
    assert psnr(b, a) == pytest.approx(expected, abs=1e-4)
    assert psnr(torch.from_numpy(a), torch.from_numpy(b)) == pytest.approx(expected, abs=1e-4)


def test_ssim_of_identical_images_is_one():
    img = np.random.default_rng(2).random((32, 32, 3))
    assert ssim(img, img) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    "shape,noise", [((32, 32, 3), 0.1), ((40, 56, 3), 0.3), ((11, 11, 3), 0.05), ((64, 48, 3), 0.02)]
)
def test_ssim_matches_scikit_image(shape, noise):
    a, b = _pair(shape, seed=3, noise=noise)
    assert ssim(a, b) == pytest.approx(_skimage_ssim(a, b), abs=1e-4)
    tb, ta = torch.from_numpy(b).float(), torch.from_numpy(a).float()
    assert ssim(tb, ta) == pytest.approx(_skimage_ssim(b, a), abs=1e-4)


def test_ssim_matches_scikit_image_on_brightness_and_contrast_changes():
    y, x = np.meshgrid(np.linspace(0, 1, 48), np.linspace(0, 1, 48), indexing="ij")
    img = np.stack([np.sin(6 * x) * 0.4 + 0.5, y, x * y], axis=-1)
    for other in (img * 0.5 + 0.2, np.clip(img + 0.15, 0, 1), 1.0 - img):
        assert ssim(other, img) == pytest.approx(_skimage_ssim(other, img), abs=1e-4)


@settings(max_examples=15, deadline=None)
@given(h=st.integers(11, 24), w=st.integers(11, 24), seed=st.integers(0, 10_000), noise=st.floats(0.0, 0.5))
def test_ssim_matches_scikit_image_property(h, w, seed, noise):
    a, b = _pair((h, w, 3), seed=seed, noise=noise)
    assert ssim(a, b) == pytest.approx(_skimage_ssim(a, b), abs=1e-4)


def test_bad_inputs_raise_value_error():
    img = np.zeros((16, 16, 3))
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((10, 16, 3)), np.zeros((10, 16, 3)))
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(img, np.zeros((16, 15, 3)))
    with pytest.raises(ValueError, match=r"\[H, W, C\]"):
        psnr(np.zeros((16, 16)), np.zeros((16, 16)))
    with pytest.raises(ValueError, match="255"):
        ssim(np.zeros((16, 16, 3), np.uint8), np.zeros((16, 16, 3), np.uint8))
