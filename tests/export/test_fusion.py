"""Color fusion across views (mean and robust) and the per-view color harmonisation."""

import numpy as np

from va_plugin.export.fusion import apply_harmonisation, fuse, harmonise, weighted_medoid


def test_a_wrong_view_is_outvoted_by_three_agreeing_ones():
    red, blue = [0.9, 0.1, 0.1], [0.1, 0.2, 0.9]
    colors = np.array([[red, red, red, blue]] * 200, np.float32)
    colors[:, :3] += np.random.default_rng(0).normal(0, 0.01, (200, 3, 3)).astype(np.float32)
    weights = np.tile(np.float32([0.5, 0.6, 0.7, 1.0]), (200, 1))  # the wrong view is the most head-on
    robust, share = fuse(colors, weights, "robust")
    mean, _ = fuse(colors, weights, "mean")
    assert np.abs(robust - red).max() < 0.05
    assert share[:, 3].max() < 0.02
    assert np.abs(mean - red).max() > 0.2  # a plain average would ghost


def test_agreeing_views_fuse_to_their_weighted_mean_either_way():
    rng = np.random.default_rng(1)
    colors = np.repeat(rng.uniform(0, 1, (100, 1, 3)), 4, 1).astype(np.float32)
    colors += rng.normal(0, 0.005, colors.shape).astype(np.float32)
    weights = rng.uniform(0.1, 1, (100, 4)).astype(np.float32)
    weights[:10, 2:] = 0
    robust, _ = fuse(colors, weights, "robust")
    mean, _ = fuse(colors, weights, "mean")
    assert np.abs(robust - mean).max() < 0.01


def test_medoid_picks_a_visible_color():
    colors = np.float32([[[0, 0, 0], [1, 1, 1], [0.9, 0.9, 0.9]]])
    assert np.allclose(weighted_medoid(colors, np.float32([[1, 1, 0]])), [0, 0, 0])  # tie: first
    assert np.allclose(weighted_medoid(colors, np.float32([[1, 1, 1]])), [0.9, 0.9, 0.9])


def test_harmonise_recovers_each_views_gains_against_the_reference():
    """Three views of the same colors, view 1 brighter, view 2 darker with a blob of wrong color on 10% of
    its points: the fitted per-view gains undo the casts (view 0 stays fixed), the blob does not bend them."""
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.1, 0.8, size=(2000, 3)).astype(np.float32)
    gain = np.array([[1.0, 1.0, 1.0], [1.12, 1.08, 0.92], [0.88, 0.92, 1.06]], np.float32)
    colors = truth[:, None] * gain[None]
    colors[:200, 2] = [0.9, 0.1, 0.9]  # a hallucinated blob in view 2
    weights = np.ones((2000, 3), np.float32)
    weights[1000:, 1] = 0.0  # view 1 sees half the points
    gains = harmonise(colors, weights)
    np.testing.assert_array_equal(gains[0], 1.0)
    np.testing.assert_allclose(gains[1:], 1.0 / gain[1:], rtol=0.005)
    fixed = apply_harmonisation(colors, weights, gains)
    assert np.abs(fixed[200:, 2] - truth[200:]).max() < 0.005 and np.abs(fixed[:1000, 1] - truth[:1000]).max() < 0.005
    np.testing.assert_array_equal(fixed[1000:, 1], colors[1000:, 1])  # where a view sees nothing, nothing changes
    colors[:, 1] *= 1.3  # beyond the trusted cast (MAX_GAIN): view 1 is left alone, view 2 still fitted
    gains = harmonise(colors, weights)
    np.testing.assert_array_equal(gains[1], 1.0)
    np.testing.assert_allclose(gains[2], 1.0 / gain[2], rtol=0.005)


def test_harmonise_leaves_views_without_overlap_alone():
    colors = np.random.default_rng(1).uniform(size=(100, 2, 3)).astype(np.float32)
    weights = np.zeros((100, 2), np.float32)
    weights[:50, 0] = weights[50:, 1] = 1.0
    np.testing.assert_array_equal(harmonise(colors, weights), 1.0)
