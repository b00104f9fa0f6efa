"""Geometry metrics between a reconstructed and a ground-truth ``trimesh.Trimesh`` in one world frame.

Distances are in world units (objects fill a unit box: a Chamfer distance of 0.01 is 1% of the size).
Chamfer and F-score compare uniform surface samples point to point, so they have a sampling floor:
two samplings of a surface of area ``A`` with ``n`` points each sit about ``0.5 * sqrt(A / n)`` apart
(a sphere of diameter 1 at 100k samples: ~0.0028); a mesh compared with itself shows this floor.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from va_plugin.utils.interrupts import interrupt_deferred

Bound = float | Sequence[Sequence[float]] | np.ndarray

# Rays per query point for the inside test; odd, so the majority vote never ties.
OCCUPANCY_RAYS = 3


def _check_mesh(mesh, name: str) -> trimesh.Trimesh:
    """The mesh itself, or a clear error for a non-mesh, an empty mesh or one of zero area."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise TypeError(
            f"{name} must be a trimesh.Trimesh, got {type(mesh).__name__} "
            "(load files with trimesh.load(path, force='mesh'))"
        )
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise ValueError(f"{name} is empty (no faces); nothing to evaluate")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(f"{name} has non-finite vertex coordinates")
    if not mesh.area > 0.0:
        raise ValueError(f"{name} has zero surface area (all faces degenerate)")
    return mesh


def sample_surface(mesh: trimesh.Trimesh, n: int, seed: int | np.random.SeedSequence = 0) -> np.ndarray:
    """``n`` points drawn uniformly over the surface area, ``[n, 3]`` float64; the same ``seed`` (an int
    or a ``SeedSequence``) gives the same points."""
    mesh = _check_mesh(mesh, "mesh")
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    rng = np.random.default_rng(seed)
    areas = mesh.area_faces
    face_idx = rng.choice(len(areas), size=n, p=areas / areas.sum())
    tri = mesh.triangles[face_idx]  # [n, 3 corners, 3]
    u, v = rng.random(n), rng.random(n)
    # Fold points of the unit square's far half back into the triangle.
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    return tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])


def nearest_distances(
    pred_mesh: trimesh.Trimesh, gt_mesh: trimesh.Trimesh, n_samples: int = 100_000, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``(pred_to_gt [n], gt_to_pred [n])``: each sample's distance to the other mesh's closest sample;
    the meshes get independent sample streams spawned from ``seed``."""
    _check_mesh(pred_mesh, "pred_mesh")
    _check_mesh(gt_mesh, "gt_mesh")
    pred_seed, gt_seed = np.random.SeedSequence(seed).spawn(2)
    pred_pts = sample_surface(pred_mesh, n_samples, pred_seed)
    gt_pts = sample_surface(gt_mesh, n_samples, gt_seed)
    pred_to_gt, _ = cKDTree(gt_pts).query(pred_pts, k=1)
    gt_to_pred, _ = cKDTree(pred_pts).query(gt_pts, k=1)
    return pred_to_gt, gt_to_pred


def _chamfer(pred_to_gt: np.ndarray, gt_to_pred: np.ndarray) -> float:
    """Mean of the two one-way mean distances."""
    return 0.5 * (float(pred_to_gt.mean()) + float(gt_to_pred.mean()))


def _f_score(pred_to_gt: np.ndarray, gt_to_pred: np.ndarray, threshold: float) -> tuple[float, float, float]:
    """``(f_score, precision, recall)`` at a distance threshold; F is 0 when both are 0."""
    precision = float(np.mean(pred_to_gt < threshold))
    recall = float(np.mean(gt_to_pred < threshold))
    denom = precision + recall
    return (2.0 * precision * recall / denom if denom > 0 else 0.0), precision, recall


def chamfer_distance(
    pred_mesh: trimesh.Trimesh, gt_mesh: trimesh.Trimesh, n_samples: int = 100_000, seed: int = 0
) -> float:
    """Symmetric Chamfer distance ``0.5 * (mean_p min_g |p - g| + mean_g min_p |g - p|)`` (Euclidean, not
    squared) over ``n_samples`` surface samples of each mesh. Two spheres shifted by d give about d / 2."""
    return _chamfer(*nearest_distances(pred_mesh, gt_mesh, n_samples, seed))


def f_score(
    pred_mesh: trimesh.Trimesh,
    gt_mesh: trimesh.Trimesh,
    threshold: float = 0.01,
    n_samples: int = 100_000,
    seed: int = 0,
) -> float:
    """F-score in [0, 1]: harmonic mean of precision (share of pred samples within ``threshold`` of a gt
    sample) and recall (the other way round). Keep ``threshold`` well above the sampling floor."""
    return _f_score(*nearest_distances(pred_mesh, gt_mesh, n_samples, seed), threshold)[0]


def _grid_box(pred_mesh: trimesh.Trimesh, gt_mesh: trimesh.Trimesh, bound: Bound | None) -> np.ndarray:
    """The evaluation box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` from ``bound``: None (union of both
    bounding boxes), a float ``b`` (``[-b, b]^3``) or a ``[2, 3]`` array of corners."""
    if bound is None:
        return np.stack([np.minimum(pred_mesh.bounds[0], gt_mesh.bounds[0]),
                         np.maximum(pred_mesh.bounds[1], gt_mesh.bounds[1])])
    if np.isscalar(bound):
        b = float(bound)
        box = np.array([[-b] * 3, [b] * 3])
    else:
        box = np.asarray(bound, dtype=np.float64)
    if box.shape != (2, 3) or not np.all(box[1] > box[0]):
        raise ValueError(f"bound must be a positive float or [[xmin,ymin,zmin],[xmax,ymax,zmax]], got {bound!r}")
    return box


def voxel_centres(box: np.ndarray, resolution: int) -> np.ndarray:
    """Centres of a ``resolution^3`` grid of equal cells filling ``box``, ``[R, R, R, 3]`` float32."""
    axes = [box[0, i] + (np.arange(resolution) + 0.5) * (box[1, i] - box[0, i]) / resolution for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).astype(np.float32)


def occupancy(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Inside test of ``[..., 3]`` points against a mesh, bool ``[...]``: open3d's ray-parity occupancy
    with a majority vote over ``OCCUPANCY_RAYS`` rays. Exact for watertight meshes."""

    with interrupt_deferred():  # heavy import, only needed here; a Ctrl-C during it fails the import
        import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(mesh.faces, dtype=np.uint32)),
    )
    query = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
    return scene.compute_occupancy(query, nsamples=OCCUPANCY_RAYS).numpy() > 0.5


def volume_iou(
    pred_mesh: trimesh.Trimesh, gt_mesh: trimesh.Trimesh, resolution: int = 64, bound: Bound | None = None
) -> float:
    """Volumetric IoU ``|A ∩ B| / |A ∪ B|`` in [0, 1] of the solids the meshes enclose, tested at the
    centres of a ``resolution^3`` grid over :func:`_grid_box`. Warns for a mesh that is not watertight;
    raises ``ValueError`` when neither mesh occupies any grid point."""
    for mesh, name in ((pred_mesh, "pred_mesh"), (gt_mesh, "gt_mesh")):
        _check_mesh(mesh, name)
        if not mesh.is_watertight:
            warnings.warn(f"{name} is not watertight: its volume IoU is approximate", stacklevel=2)
    if resolution < 2:
        raise ValueError(f"resolution must be at least 2, got {resolution}")
    points = voxel_centres(_grid_box(pred_mesh, gt_mesh, bound), resolution)
    a, b = occupancy(pred_mesh, points), occupancy(gt_mesh, points)
    union = np.count_nonzero(a | b)
    if union == 0:
        raise ValueError("neither mesh occupies any grid point; are they closed surfaces inside the bound?")
    return float(np.count_nonzero(a & b) / union)


def geometry_metrics(
    pred_mesh: trimesh.Trimesh,
    gt_mesh: trimesh.Trimesh,
    n_samples: int = 100_000,
    seed: int = 0,
    threshold: float = 0.01,
    resolution: int = 64,
    bound: Bound | None = None,
) -> dict:
    """Chamfer distance, F-score (with precision and recall) and volume IoU, plus the parameters used;
    the same values as the separate functions with the same arguments."""
    pred_to_gt, gt_to_pred = nearest_distances(pred_mesh, gt_mesh, n_samples, seed)
    fs, precision, recall = _f_score(pred_to_gt, gt_to_pred, threshold)
    return {
        "chamfer_distance": _chamfer(pred_to_gt, gt_to_pred),
        "f_score": fs,
        "precision": precision,
        "recall": recall,
        "volume_iou": volume_iou(pred_mesh, gt_mesh, resolution, bound),
        "params": {
            "n_samples": n_samples,
            "seed": seed,
            "threshold": threshold,
            "resolution": resolution,
            "bound": None if bound is None else np.asarray(bound, dtype=float).tolist(),
        },
    }
