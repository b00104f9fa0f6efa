"""Unseen texels take the colour of the nearest seen surface, weighted by distance and normal agreement."""

from __future__ import annotations

import numpy as np

from va_plugin.export.fill import NORMAL_FLOOR, fill_from_seen


def test_an_unseen_point_takes_the_inverse_distance_mean_of_its_seen_neighbours():
    points = np.float32([[0, 0, 0], [1, 0, 0], [3, 0, 0]])
    normals = np.float32([[0, 0, 1]] * 3)
    colors = np.float32([[0, 0, 0], [1, 1, 1], [0.2, 0.4, 0.6]])
    seen = np.array([False, True, True])
    out = fill_from_seen(points, normals, colors, seen, neighbours=2)
    w = np.array([1 / 1, 1 / 3]) / (1 + 1 / 3)  # distances 1 and 3
    np.testing.assert_allclose(out[0], w[0] * colors[1] + w[1] * colors[2], rtol=1e-6)
    np.testing.assert_array_equal(out[1:], colors[1:])  # seen rows are left alone


def test_a_neighbour_facing_away_counts_for_little():
    points = np.float32([[0, 0, 0], [0, 0, 1], [0, 0, -1]])
    normals = np.float32([[0, 0, 1], [0, 0, 1], [0, 0, -1]])  # the second seen point faces the other way
    colors = np.float32([[9, 9, 9], [1, 0, 0], [0, 0, 1]])
    out = fill_from_seen(points, normals, colors, np.array([False, True, True]), neighbours=2)
    np.testing.assert_allclose(out[0], (colors[1] + NORMAL_FLOOR * colors[2]) / (1 + NORMAL_FLOOR), rtol=1e-6)


def test_nothing_seen_or_nothing_unseen_changes_nothing():
    rng = np.random.default_rng(0)
    points, colors = rng.random((5, 3)).astype(np.float32), rng.random((5, 3)).astype(np.float32)
    normals = np.tile(np.float32([0, 0, 1]), (5, 1))
    for seen in (np.zeros(5, bool), np.ones(5, bool)):
        np.testing.assert_array_equal(fill_from_seen(points, normals, colors, seen), colors)


def test_the_fill_matches_a_brute_force_nearest_neighbour_reference():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(600, 3)).astype(np.float32)
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    colors = rng.random((600, 3)).astype(np.float32)
    seen = points[:, 2] > -0.3  # the underside unseen, as on a rig above the object
    out = fill_from_seen(points, normals, colors, seen)
    known, unknown = np.nonzero(seen)[0], np.nonzero(~seen)[0]
    distance = np.linalg.norm(points[unknown, None] - points[None, known], axis=-1).astype(np.float64)
    nearest = np.argsort(distance, axis=1)[:, :8]
    d = np.take_along_axis(distance, nearest, 1)
    agree = np.einsum("mc,mkc->mk", normals[unknown], normals[known[nearest]])
    w = np.clip(agree, NORMAL_FLOOR, 1.0) / np.maximum(d, 1e-6)
    expected = np.einsum("mk,mkc->mc", w / w.sum(1, keepdims=True), colors[known[nearest]])
    np.testing.assert_allclose(out[unknown], expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(out[seen], colors[seen])
