"""Colors for the surface no input view sees, taken from the nearest surface that some view does see.

A texel no view sees has no photograph of its own. The field's color there was never supervised (it is
often the background's white), so such texels take the mean color of the nearest seen texels in 3D instead,
weighted by inverse distance and by how well their normals agree (so the far side of a thin part does not
paint this one when a same-facing neighbour is about as near).
"""

from __future__ import annotations

import numpy as np

NEIGHBOURS = 8
"""Seen texels averaged for each unseen one."""
NORMAL_FLOOR = 0.05
"""Weight factor of a neighbour whose normal points away (the dot product is clamped up to this)."""


def fill_from_seen(points: np.ndarray, normals: np.ndarray, colors: np.ndarray, seen: np.ndarray,
                   neighbours: int = NEIGHBOURS) -> np.ndarray:
    """``colors [m, 3]`` with every row where ``seen [m]`` is False replaced by the weighted mean color of
    its ``neighbours`` nearest seen points (``points, normals [m, 3]``, unit normals). Returns a new array;
    with nothing seen (or nothing unseen) the colors come back unchanged."""
    import open3d.core as o3c

    out = np.array(colors, dtype=np.float32, copy=True)
    seen = np.asarray(seen, bool)
    if seen.all() or not seen.any():
        return out
    known = np.nonzero(seen)[0]
    unknown = np.nonzero(~seen)[0]
    k = int(min(max(neighbours, 1), len(known)))
    # open3d's search (threaded) rather than scipy's KD-tree: unseen texels lie far from the seen ones, where
    # a KD-tree query visits many nodes; the neighbours are the same
    search = o3c.nns.NearestNeighborSearch(o3c.Tensor(np.ascontiguousarray(points[known], np.float32)))
    search.knn_index()
    nearest, squared = search.knn_search(o3c.Tensor(np.ascontiguousarray(points[unknown], np.float32)), k)
    distance = np.sqrt(np.maximum(squared.numpy().astype(np.float64), 0.0)).reshape(len(unknown), k)
    nearest = known[nearest.numpy().astype(np.int64).reshape(len(unknown), k)]
    agree = np.einsum("mc,mkc->mk", normals[unknown], normals[nearest])
    weight = np.clip(agree, NORMAL_FLOOR, 1.0) / np.maximum(distance, 1e-6)
    weight /= np.maximum(weight.sum(1, keepdims=True), 1e-12)
    out[unknown] = np.einsum("mk,mkc->mc", weight, out[nearest]).astype(np.float32)
    return out
