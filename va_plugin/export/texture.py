"""Textured meshes: a UV atlas for an extracted mesh and a texture baked from the input views.

Per texel (a point on the surface): project it into every training view, keep the views that see it
(ray casting against the mesh itself), weight each by how head-on it sees the surface and how far the
point lies from that view's silhouette edge (edge pixels are blended with the background), then fuse:

- ``mean``: the weighted average of the visible views' colours (ghosting where views disagree);
- ``robust``: the weighted medoid of the visible colours (the view colour closest to the others) as a
  consensus, then a few reweighting rounds in which a view loses weight when it deviates from the
  consensus by more than its own noise (the median deviation of that view over the whole mesh).

Texels no view sees take the field's colour (a fall-back callable); empty texels around the charts are
filled by dilation so that bilinear filtering and mip-mapping do not bleed the background into seams.

Conventions: ``uv`` has v up (OBJ, trimesh); texel ``(row r, column c)`` of an ``S x S`` texture sits at
``uv = ((c + 0.5) / S, 1 - (r + 0.5) / S)``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional

import cv2
import numpy as np
import torch
import trimesh
from tqdm import tqdm

from va_plugin.cameras import Cameras
from va_plugin.data.images import write_image
from va_plugin.data.scenes.raycast import o3d, smooth_vertex_normals
from va_plugin.errors import VAError
from va_plugin.utils.memory import check_texture_memory

TEXTURE_FORMATS = (".glb", ".obj")
MIN_TEXTURE_SIZE = 16
MAX_TEXTURE_SIZE = 8192
"""Largest texture side accepted (8192^2 texels hold ~64M surface samples, far beyond any input view)."""
FUSIONS = ("robust", "mean")

EDGE_PIXELS = 3.0
"""A view's weight rises from 0 at EDGE_MARGIN pixels inside its silhouette to 1 this many pixels further."""
EDGE_MARGIN = 1.5
"""Pixels this close to the silhouette edge blend the object with the background: they give no colour."""
MIN_COS = 0.1
"""Views seeing the surface more grazing than this (cos of the angle to the normal) are ignored."""
NOISE_FLOOR = 0.02
"""Smallest per-view noise (RGB distance) of the robust fusion, so a near-perfect view is not over-trusted."""
OUTLIER_SCALE = 2.0
"""A view deviating from the consensus by this many times its noise keeps 1/2 of its weight (Cauchy)."""
ROBUST_ROUNDS = 3
HARMONISE_ROUNDS = 8
"""Reweighting rounds of the per-view colour fit (a blob on 10% of a view's texels needs ~6 to stop pulling)."""
FIT_WEIGHT = 0.25
"""Only texels that both views of a pair see well (weight >= this: within 60 degrees of head-on and away
from their silhouette edges) enter the colour fit; grazing samples are blurred and misregistered."""
RIDGE = 1e-3
"""Pull of each view's gains towards 1, per unit of the mean overlap weight of a view (it pins a view that
overlaps no other)."""
MAX_GAIN = 1.2
"""Largest colour gain (and 1 / smallest) the harmonisation trusts: a view fitted beyond it in any channel
is left as it is. Generators' casts are a few percent (level 2, calibrated to SyncDreamer: 4% per
channel); on GSO a fit that reached 0.67 in every channel came from misregistered overlaps."""
INCONSISTENCY_SCALE = 0.05
"""With inconsistency maps: a view keeps exp(-map / this) of its weight (0.05 = a clear disagreement)."""
PADDING_TEXELS = 16
MAX_TEXTURE_FACES = 40_000
"""Meshes with more faces are simplified (quadric decimation) before the UV unwrap, whose time grows
steeply with the face count on noisy surfaces (GSO cream, 83k faces: 82 s, at 40k 19 s, texture unchanged;
at 20k it lost detail: benchmarks/RESULTS.md, "Faces before the unwrap")."""


@dataclass
class TexturedMesh:
    """A mesh with per-vertex UVs and its texture.

    Attributes:
        vertices: ``[v, 3]`` float32 (split along UV seams).
        faces: ``[f, 3]`` int64.
        uv: ``[v, 2]`` float32 in [0, 1], v up.
        image: ``[S, S, 3]`` float32 RGB in [0, 1].
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    image: np.ndarray

    def to_trimesh(self) -> trimesh.Trimesh:
        from PIL import Image

        texture = Image.fromarray((np.clip(self.image, 0, 1) * 255 + 0.5).astype(np.uint8))
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=texture, metallicFactor=0.0,
                                                       roughnessFactor=1.0, name="baked")
        visual = trimesh.visual.TextureVisuals(uv=self.uv, material=material)
        return trimesh.Trimesh(self.vertices, self.faces, visual=visual, process=False)


@dataclass
class Views:
    """Input views to bake from.

    Attributes:
        cameras: ``n`` cameras.
        images: ``[n, H, W, 3]`` float32, composited on the background.
        masks: ``[n, H, W]`` bool foreground masks, or None (then the mesh's own silhouettes are used).
        inconsistency: ``[n, h, w]`` float32 per-view disagreement maps (any resolution), or None.
    """

    cameras: Cameras
    images: np.ndarray
    masks: Optional[np.ndarray] = None
    inconsistency: Optional[np.ndarray] = None

    def __len__(self) -> int:
        return len(self.images)


@dataclass
class BakeReport:
    """What the bake did: per-view weight maps in texture space and counts."""

    weight_maps: np.ndarray  # [n, S, S] share of each view in each texel's colour
    covered: int  # texels on the surface
    seen: int  # of those, texels at least one view sees
    view_texels: List[int]  # texels each view sees
    seconds: Dict[str, float] = field(default_factory=dict)
    gains: Optional[np.ndarray] = None  # [n, 3] per-view colour gain of the harmonisation (None: off)
    field_share: Optional[float] = None  # mean share of the field's colour over the surface (None: no weight)

    def summary(self) -> Dict[str, object]:
        total = np.maximum(self.weight_maps.sum(0), 1e-12)
        share = [float(m.sum() / max(total[total > 1e-12].size, 1)) for m in self.weight_maps]
        out = {"texels_on_surface": self.covered, "texels_seen": self.seen,
               "texels_fallback": self.covered - self.seen, "view_texels": self.view_texels,
               "view_share": [round(s, 4) for s in share],
               "seconds": {k: round(v, 2) for k, v in self.seconds.items()}}
        if self.gains is not None:
            out["view_colour_gain"] = np.round(self.gains, 4).tolist()
        if self.field_share is not None:
            out["field_share"] = round(self.field_share, 4)
        return out


def check_texture_size(size: int) -> None:
    """Refuse texture sizes that are not a power of two or outside [16, 8192]."""
    if size < MIN_TEXTURE_SIZE or size > MAX_TEXTURE_SIZE or size & (size - 1):
        raise VAError(f"--texture-size must be a power of two from {MIN_TEXTURE_SIZE} to {MAX_TEXTURE_SIZE}, "
                      f"got {size}")


def simplify_for_texture(mesh: trimesh.Trimesh, max_faces: Optional[int] = MAX_TEXTURE_FACES) -> trimesh.Trimesh:
    """``mesh`` with at most ``max_faces`` faces (open3d's quadric decimation, which keeps the shape where
    it is flat), or ``mesh`` itself when it has no more, or ``max_faces`` is 0 or None."""
    faces = np.asarray(mesh.faces)
    if not max_faces or len(faces) <= max_faces:
        return mesh
    if max_faces < 4:
        raise VAError(f"--max-faces must be 0 (keep every face) or at least 4, got {max_faces}")
    simple = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                       o3d.utility.Vector3iVector(faces.astype(np.int32)))
    simple = simple.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
    simple.remove_degenerate_triangles()
    simple.remove_unreferenced_vertices()
    return trimesh.Trimesh(np.asarray(simple.vertices, np.float32), np.asarray(simple.triangles, np.int64),
                           process=False)


def unwrap(mesh: trimesh.Trimesh, size: int, padding: int = 4):
    """xatlas charts packed into one ``size x size`` atlas.

    Returns ``vertices [v', 3]``, ``faces [f, 3]``, ``uv [v', 2]`` (v up) and ``source [v']``, the original
    vertex of each new one (vertices on chart seams are duplicated)."""
    import xatlas

    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        raise VAError("the mesh has no faces: nothing to texture")
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.asarray(mesh.vertices, np.float32), faces.astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = size
    pack.padding = padding
    pack.bilinear = True
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count != 1:
        # a fixed resolution lets xatlas spill charts into more atlases: scale them into one instead
        pack.resolution = 0
        pack.texels_per_unit = 0.0
        atlas.generate(xatlas.ChartOptions(), pack)
    source, new_faces, uv = atlas[0]
    uv = np.asarray(uv, np.float32).copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # xatlas' v runs down the atlas image; ours runs up
    source = np.asarray(source, np.int64)
    return np.asarray(mesh.vertices, np.float32)[source], np.asarray(new_faces, np.int64), uv, source


def rasterize_uv(uv: np.ndarray, faces: np.ndarray, size: int):
    """Which triangle covers each texel centre, and where.

    Returns ``face [S, S]`` int64 (-1 where no triangle covers the centre) and ``bary [S, S, 3]``."""
    corners = np.stack([uv[:, 0] * size, (1.0 - uv[:, 1]) * size, np.zeros(len(uv))], -1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(corners), o3d.core.Tensor(faces.astype(np.uint32)))
    rows, cols = np.meshgrid(np.arange(size, dtype=np.float32), np.arange(size, dtype=np.float32), indexing="ij")
    origins = np.stack([cols + 0.5, rows + 0.5, np.ones_like(rows)], -1).reshape(-1, 3)
    rays = np.concatenate([origins, np.broadcast_to(np.float32([0, 0, -1]), origins.shape)], -1)
    result = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays, np.float32)))
    hit = np.isfinite(result["t_hit"].numpy())
    face = np.where(hit, result["primitive_ids"].numpy().astype(np.int64), -1)
    b = result["primitive_uvs"].numpy()
    bary = np.stack([1.0 - b[:, 0] - b[:, 1], b[:, 0], b[:, 1]], -1)  # o3d: (1-u-v) a + u b + v c
    return face.reshape(size, size), bary.reshape(size, size, 3).astype(np.float32)


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image [H, W, C]`` (or ``[H, W]``) at continuous pixel coordinates ``x, y [m]`` (pixel centres at
    integers, clamped to the border): ``[m, C]`` (or ``[m]``)."""
    h, w = image.shape[:2]
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    if image.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def rays_through(cameras: Cameras, index: int, points: np.ndarray):
    """Rays of view ``index`` through world points ``[m, 3]``: ``origins, directions [m, 3]``, the points'
    distance along them ``[m]`` and their pixel coordinates ``[m, 2]`` (column, row)."""
    pts = torch.as_tensor(points, dtype=torch.float32)
    uv, _ = cameras.project(pts, index)
    idx = torch.full((len(pts),), index, dtype=torch.long)
    origins, directions = cameras.generate_rays(idx, uv[:, 1], uv[:, 0])
    distance = ((pts - origins) * directions).sum(-1)
    return origins.numpy(), directions.numpy(), distance.numpy(), uv.numpy()


def silhouette_distance(scene, cameras: Cameras, index: int, mask: Optional[np.ndarray]) -> np.ndarray:
    """Distance in pixels ``[H, W]`` to the nearest pixel outside the object in view ``index`` (0 outside);
    the object is where the mesh is hit and, when given, ``mask`` is set."""
    _, rows, cols = cameras.pixel_grid(index)
    origins, directions = cameras.generate_rays(torch.full_like(rows, index), rows, cols)
    rays = np.concatenate([origins.numpy(), directions.numpy()], -1).astype(np.float32)
    inside = np.isfinite(scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()).reshape(cameras.height,
                                                                                           cameras.width)
    if mask is not None:
        inside &= mask
    padded = np.pad(inside.astype(np.uint8), 1)  # the image border counts as an edge
    return cv2.distanceTransform(padded, cv2.DIST_L2, 5)[1:-1, 1:-1]


def view_samples(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, normals: np.ndarray, views: Views,
                 edge_pixels: float = EDGE_PIXELS, progress: bool = False):
    """Colour and weight of every view at every surface point.

    Args:
        vertices, faces: the mesh (its triangles occlude).
        points, normals: ``[m, 3]`` surface points and unit outward normals.
    Returns:
        colours ``[m, n, 3]``, weights ``[m, n]`` (0 where view k does not see the point) and
        ``in_view [n]`` bool: whether any pixel of view k shows the mesh (inside the view's mask).
    """
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    edges = np.linalg.norm(vertices[faces[:, 1]] - vertices[faces[:, 0]], axis=-1)
    tolerance = 0.5 * float(np.median(edges)) if len(edges) else 1e-3  # depth slack of the visibility test
    m, n = len(points), len(views)
    colours = np.zeros((m, n, 3), np.float32)
    weights = np.zeros((m, n), np.float32)
    in_view = np.zeros(n, bool)
    cameras = views.cameras
    for k in tqdm(range(n), desc="projecting views", disable=not progress):
        edge = silhouette_distance(scene, cameras, k, None if views.masks is None else views.masks[k])
        in_view[k] = bool(edge.max() > 0)
        origins, directions, distance, pix = rays_through(cameras, k, points)
        cos = -(normals * directions).sum(-1)
        candidate = (cos > MIN_COS) & (distance > 0)
        candidate &= (pix[:, 0] > -0.5) & (pix[:, 0] < cameras.width - 0.5)
        candidate &= (pix[:, 1] > -0.5) & (pix[:, 1] < cameras.height - 0.5)
        idx = np.nonzero(candidate)[0]
        if len(idx) == 0:
            continue
        rays = np.concatenate([origins[idx], directions[idx]], -1).astype(np.float32)
        t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        idx = idx[t_hit >= distance[idx] - tolerance]  # nothing in front of the point
        x, y = pix[idx, 0], pix[idx, 1]
        w = cos[idx] ** 2 * np.clip((bilinear(edge, x, y) - EDGE_MARGIN) / max(edge_pixels, 1e-6), 0.0, 1.0)
        if views.inconsistency is not None:
            imap = views.inconsistency[k]
            sx, sy = imap.shape[1] / cameras.width, imap.shape[0] / cameras.height
            spread = bilinear(imap, (x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5)
            w = w * np.exp(-np.maximum(spread, 0.0) / INCONSISTENCY_SCALE)
        keep = w > 0
        colours[idx[keep], k] = bilinear(views.images[k], x[keep], y[keep])
        weights[idx[keep], k] = w[keep]
    return colours, weights, in_view


def weighted_medoid(colours: np.ndarray, weights: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """Per point, the visible colour with the least weighted sum of distances to the other visible
    colours: ``colours [m, n, 3]``, ``weights [m, n]`` -> ``[m, 3]``."""
    # with at most two visible views the medoid is the heavier one: no pairwise distances needed
    out = np.take_along_axis(colours, np.argmax(weights, axis=1)[:, None, None], axis=1)[:, 0].astype(np.float32)
    many = np.nonzero((weights > 0).sum(1) > 2)[0]
    for s in range(0, len(many), chunk):
        rows = many[s:s + chunk]
        c, w = torch.from_numpy(colours[rows]), torch.from_numpy(weights[rows])
        cost = torch.bmm(torch.cdist(c, c), w[:, :, None])[:, :, 0]  # [m, n]: weighted distance to the others
        cost[w <= 0] = torch.inf
        best = cost.argmin(1)
        out[rows] = c[torch.arange(len(rows)), best].numpy()
    return out


def view_noise(residual: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Each view's own noise ``[n]``: the median distance of its colours from the consensus where at least
    three views (else two) see a point. It is capped at twice the median over all views, so that a view
    that is wrong nearly everywhere cannot declare its errors to be its noise, and floored at NOISE_FLOOR."""
    count = visible.sum(1)
    pooled_sel = visible & (count >= 2)[:, None]
    pooled = float(np.median(residual[pooled_sel])) if pooled_sel.any() else NOISE_FLOOR
    cap = max(2.0 * pooled, NOISE_FLOOR)
    noise = np.full(residual.shape[1], cap, np.float32)
    for k in range(residual.shape[1]):
        for least in (3, 2):
            sel = visible[:, k] & (count >= least)
            if sel.sum() >= 16:
                noise[k] = float(np.median(residual[sel, k]))
                break
    return np.clip(noise, NOISE_FLOOR, cap)


def harmonise(colours: np.ndarray, weights: np.ndarray, reference: int = 0, rounds: int = HARMONISE_ROUNDS,
              max_gain: Optional[float] = None):
    """Per-view colour gains that make the views agree where they overlap: ``gains [n, 3]`` with view
    ``reference`` fixed at 1 (the generator's conditioning view by this project's convention, as for the
    per-view camera and appearance corrections).

    Per channel, a weighted least-squares fit of ``a_k c_k = a_l c_l`` over every texel that two views k
    and l both see well (weights >= FIT_WEIGHT; weight sqrt(w_k w_l)), with a weak ridge towards 1 so that
    a view without overlaps stays as it is; reweighting rounds (Cauchy, scale from the median residual)
    keep blobs, occlusion errors and misregistered edges out of the fit. Gains only: a gain and an offset
    trade off on the near-uniform colours most overlaps hold (fitted together on the GSO objects they ran
    to 0.5 and +0.3 where the true casts were 3%). A view whose gains leave [1 / MAX_GAIN, MAX_GAIN] is
    distrusted (kept at 1) and the others are fitted again (``max_gain``: that bound, default MAX_GAIN;
    ``inf`` keeps every fit)."""
    max_gain = MAX_GAIN if max_gain is None else max_gain
    m, n = weights.shape
    gains = np.ones((n, 3), np.float64)
    visible = weights >= FIT_WEIGHT
    pairs = []
    for k in range(n):
        for l in range(k + 1, n):
            both = np.nonzero(visible[:, k] & visible[:, l])[0]
            if len(both):
                pairs.append((k, l, both, np.sqrt(weights[both, k] * weights[both, l]).astype(np.float64)))
    if not pairs:
        return gains.astype(np.float32)
    ridge = RIDGE * sum(float(w.sum()) for *_, w in pairs) / n + 1e-9
    fixed = {reference}
    while True:  # a view whose fit leaves the plausible range is distrusted: kept at 1, the others re-fitted
        keep = [i for i in range(n) if i not in fixed]
        if not keep or not pairs:
            break
        gains[:] = 1.0
        for channel in range(3):
            samples = [(k, l, w, colours[both, k, channel].astype(np.float64),
                        colours[both, l, channel].astype(np.float64)) for k, l, both, w in pairs]
            gains[keep, channel] = _fit_channel(samples, n, keep, ridge, rounds)
        wild = [k for k in keep if np.any(gains[k] > max_gain) or np.any(gains[k] < 1.0 / max_gain)]
        if not wild:
            break
        fixed.update(wild)
        gains[wild] = 1.0
        pairs = [p for p in pairs if p[0] not in wild and p[1] not in wild]  # nor does it pull the others
    return gains.astype(np.float32)


def _fit_channel(samples, n: int, keep: List[int], ridge: float, rounds: int) -> np.ndarray:
    """Gains of views ``keep`` for one colour channel (the other views held at 1): iteratively reweighted
    least squares of ``a_k c_k - a_l c_l`` over ``samples``, one ``(k, l, weight, c_k, c_l)`` per pair
    of views of :func:`harmonise` (float64 arrays of the texels both see well)."""
    gains = np.ones(n)
    robust = [np.ones(len(w)) for _, _, w, _, _ in samples]
    held = [i for i in range(n) if i not in keep]
    for _ in range(rounds + 1):
        normal = np.zeros((n, n))
        for (k, l, w, ck, cl), r in zip(samples, robust):
            wr = w * r
            normal[k, k] += float(np.dot(wr, ck * ck))
            normal[l, l] += float(np.dot(wr, cl * cl))
            normal[k, l] -= float(np.dot(wr, ck * cl))
            normal[l, k] = normal[k, l]
        normal[np.arange(n), np.arange(n)] += ridge
        rhs = np.full(n, ridge) - normal[:, held].sum(1)  # ridge towards 1; the held views' gains are 1
        gains[keep] = np.linalg.solve(normal[np.ix_(keep, keep)], rhs[keep])
        residuals = [gains[k] * ck - gains[l] * cl for k, l, _, ck, cl in samples]
        flat = np.abs(np.concatenate(residuals))
        # the median from a strided subsample: the scale of the Cauchy weights needs no more precision
        scale = max(1.4826 * float(np.median(flat[:: max(1, len(flat) // 65536)])), 1e-3)
        robust = [1.0 / (1.0 + (res / (OUTLIER_SCALE * scale)) ** 2) for res in residuals]
    return gains[keep]


def apply_harmonisation(colours: np.ndarray, weights: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``colours [m, n, 3]`` with each view's gains applied where it sees the point (clipped to [0, 1])."""
    out = np.clip(colours * gains[None], 0.0, 1.0).astype(np.float32)
    return np.where((weights > 0)[..., None], out, colours)


def fuse(colours: np.ndarray, weights: np.ndarray, mode: str = "robust", anchor: Optional[int] = None):
    """Fused colour ``[m, 3]`` and the final per-view weights ``[m, n]`` (normalised per point; zero rows
    where no view sees the point). ``anchor``: with robust fusion, the column whose colour is the first
    consensus in place of the weighted medoid (the field's colour, when it joins as a column): views are
    then judged by how far they lie from it."""
    if mode not in FUSIONS:
        raise VAError(f"unknown fusion {mode!r}; use one of {', '.join(FUSIONS)}")
    colours, weights = np.ascontiguousarray(colours, np.float32), np.ascontiguousarray(weights, np.float32)
    c, w0 = torch.from_numpy(colours), torch.from_numpy(weights)
    w = w0
    if mode == "robust" and colours.shape[1] > 1:
        consensus = c[:, anchor] if anchor is not None else torch.from_numpy(weighted_medoid(colours, weights))
        residual = (c - consensus[:, None]).norm(dim=-1)
        noise = torch.from_numpy(view_noise(residual.numpy(), weights > 0))
        for _ in range(ROBUST_ROUNDS):
            w = w0 / (1.0 + (residual / (OUTLIER_SCALE * noise)) ** 2)
            consensus = torch.einsum("mn,mnc->mc", w, c) / w.sum(1, keepdim=True).clamp_min(1e-12)
            residual = (c - consensus[:, None]).norm(dim=-1)
    total = w.sum(1, keepdim=True)
    share = torch.where(total > 1e-12, w / total.clamp_min(1e-12), torch.zeros_like(w))
    return torch.einsum("mn,mnc->mc", share, c).numpy(), share.numpy()


def dilate(image: np.ndarray, filled: np.ndarray, iterations: int = PADDING_TEXELS) -> np.ndarray:
    """Grow the filled texels of ``image [S, S, 3]`` outwards by ``iterations`` texels (mean of the filled
    3x3 neighbours), then give any still-empty texel the mean colour."""
    image = np.where(filled[..., None], image, 0.0).astype(np.float32)
    filled = filled.astype(np.float32)
    for _ in range(iterations):
        if filled.min() > 0:
            break
        total = cv2.boxFilter(image * filled[..., None], -1, (3, 3), normalize=False)
        count = cv2.boxFilter(filled, -1, (3, 3), normalize=False)
        grow = (filled == 0) & (count > 0)
        image[grow] = total[grow] / count[grow][:, None]
        filled[grow] = 1.0
    if filled.min() == 0:
        mean = image[filled > 0].mean(0) if filled.any() else np.full(3, 0.5, np.float32)
        image[filled == 0] = mean
    return image


Fallback = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""Colours ``[m, 3]`` of surface points ``[m, 3]`` with normals ``[m, 3]`` (e.g. the field's own colour)."""


def bake_texture(mesh: trimesh.Trimesh, views: Views, size: int = 1024, fusion: str = "robust",
                 fallback: Optional[Fallback] = None, progress: bool = False, atlas=None,
                 harmonise_views: Optional[bool] = None, max_faces: Optional[int] = MAX_TEXTURE_FACES,
                 field_weight: float = 0.0, field_anchor: bool = False):
    """UV-unwrap ``mesh`` (first simplified to ``max_faces``, see :func:`simplify_for_texture`) and bake its
    texture from ``views``: ``(TexturedMesh, BakeReport)``. ``atlas``: the ``(vertices, faces, uv)`` of an
    earlier :func:`unwrap` of the same mesh at the same size (the textured mesh's own), reused as it is.
    ``harmonise_views``: level each view's colours against the others (:func:`harmonise`) before fusing;
    None: with robust fusion only (mean fusion stays the plain angle-weighted average).
    ``field_weight``: with a ``fallback``, the fall-back's colour joins every texel's fusion as one more
    view of this constant weight (a view's own weight is ``cos^2`` of its angle times its edge ramp, so
    0.1 equals a view at 72 degrees); texels only grazing or edge views see lean towards the field's
    colour instead of switching to it where the last view drops out. 0: the fall-back fills unseen
    texels only. ``field_anchor`` (robust fusion with a field weight): the field's colour, not the views'
    medoid, is the consensus the views are first judged against, so a view's colour that lies far from
    the field (misprojected through a wrong surface) loses its weight even where it is the only view.

    Raises VAError for a mesh without faces, a bad texture size, or a view that sees none of the mesh."""
    check_texture_size(size)
    check_texture_memory(size, len(views))
    if fusion not in FUSIONS:
        raise VAError(f"unknown fusion {fusion!r}; use one of {', '.join(FUSIONS)}")
    if not (np.isfinite(field_weight) and field_weight >= 0.0):
        raise VAError(f"the field's weight in the bake must be a finite number >= 0, got {field_weight}")
    if field_weight > 0 and fallback is None:
        raise VAError("a field weight in the bake needs the field's colour (a fall-back)")
    if field_anchor and not (field_weight > 0 and fusion == "robust"):
        raise VAError("anchoring the bake on the field's colour needs robust fusion and a field weight > 0")
    if len(np.asarray(mesh.faces)) == 0:
        raise VAError("the mesh has no faces: nothing to texture")
    seconds = {}
    if atlas is None:
        started = time.perf_counter()
        mesh = simplify_for_texture(mesh, max_faces)
        seconds["simplify"] = time.perf_counter() - started
    started = time.perf_counter()
    vertices, faces, uv = unwrap(mesh, size)[:3] if atlas is None else atlas
    seconds["unwrap"] = time.perf_counter() - started
    started = time.perf_counter()
    face, bary = rasterize_uv(uv, faces, size)
    covered = face >= 0
    fid, b = face[covered], bary[covered]
    corners = faces[fid]
    points = np.einsum("mk,mkc->mc", b, vertices[corners]).astype(np.float32)
    vertex_normals = smooth_vertex_normals(vertices, faces)
    normals = np.einsum("mk,mkc->mc", b, vertex_normals[corners])
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    colours, weights, in_view = view_samples(vertices, faces, points, normals, views, progress=progress)
    n_views = len(views)
    view_texels = [int(c) for c in (weights > 0).sum(0)]
    blind = [k for k in range(len(views)) if not in_view[k]]
    if blind:
        raise VAError(f"training view{'s' if len(blind) > 1 else ''} {', '.join(map(str, blind))} see"
                      f"{'' if len(blind) > 1 else 's'} no texel of the mesh (the mesh lies outside "
                      f"{'their' if len(blind) > 1 else 'its'} image or mask): the mesh and the run's cameras "
                      "do not fit together")
    gains = None
    if harmonise_views if harmonise_views is not None else fusion == "robust":
        gains = harmonise(colours, weights)
        colours = apply_harmonisation(colours, weights, gains)
    seen = (weights > 0).any(1)
    if field_weight > 0:
        prior = np.clip(fallback(points, normals), 0.0, 1.0).astype(np.float32)
        colours = np.concatenate([colours, prior[:, None]], 1)
        weights = np.concatenate([weights, np.full((len(weights), 1), field_weight, np.float32)], 1)
    fused, share = fuse(colours, weights, fusion, anchor=n_views if field_anchor else None)
    field_share = float(share[:, n_views:].sum() / max(len(share), 1)) if field_weight > 0 else None
    share = share[:, :n_views]
    if fallback is not None and (~seen).any():
        if field_weight <= 0:  # (with a field weight the fusion has already given them the field's colour)
            fused[~seen] = np.clip(fallback(points[~seen], normals[~seen]), 0.0, 1.0)
        seen_or_filled = np.ones_like(seen)
    else:
        seen_or_filled = seen
    seconds["bake"] = time.perf_counter() - started
    image = np.zeros((size, size, 3), np.float32)
    filled = np.zeros((size, size), bool)
    rows, cols = np.nonzero(covered)
    image[rows, cols] = fused
    filled[rows[seen_or_filled], cols[seen_or_filled]] = True
    image = dilate(image, filled)
    maps = np.zeros((len(views), size, size), np.float32)
    maps[:, rows, cols] = share.T
    report = BakeReport(maps, int(covered.sum()), int(seen.sum()), view_texels, seconds, gains, field_share)
    return TexturedMesh(vertices, faces, uv, np.clip(image, 0.0, 1.0)), report


def run_views(pipeline, inconsistency: bool = False, progress: bool = False) -> Views:
    """The training views of a loaded run; with ``inconsistency`` (view-adaptive runs) also their
    inconsistency maps (|own-branch render - canonical render|, half resolution)."""
    dm = pipeline.datamanager
    masks = None if dm.masks is None else dm.masks.cpu().numpy().reshape(dm.images.shape[:3]) > 0.5
    maps = None
    if inconsistency:
        if not hasattr(pipeline.model.field, "branches_active") or not pipeline.model.field.branches_active():
            raise VAError("--use-inconsistency needs a view-adaptive run (va-neus, va-ngp) whose branches trained")
        from va_plugin.adaptive.diagnostics import inconsistency_maps

        maps = np.stack([v["map"] for v in inconsistency_maps(pipeline, scale=0.5, progress=progress)])
    return Views(dm.cameras.to(torch.device("cpu")), dm.images.cpu().numpy().astype(np.float32), masks, maps)


def field_fallback(model) -> Fallback:
    """The model's canonical surface colour as a fall-back for texels no view sees."""
    device = next(model.parameters()).device

    def colour(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        out = []
        was_training = model.training
        model.eval()
        try:
            for p, n in zip(np.array_split(points, max(1, len(points) // 16384 + 1)),
                            np.array_split(normals, max(1, len(normals) // 16384 + 1))):
                if len(p):
                    out.append(model.surface_color(torch.as_tensor(p, device=device),
                                                   torch.as_tensor(n, dtype=torch.float32, device=device)).cpu())
        finally:
            model.train(was_training)
        return torch.cat(out).numpy() if out else np.zeros((0, 3), np.float32)

    return colour


def check_texture_output(path: Path) -> None:
    if Path(path).suffix.lower() not in TEXTURE_FORMATS:
        raise VAError(f"a textured mesh is written as {' or '.join(TEXTURE_FORMATS)}, not {Path(path).suffix!r}")


def write_textured_mesh(textured: TexturedMesh, path: Path) -> List[Path]:
    """GLB with the texture embedded, or OBJ with its ``.mtl`` and ``.png`` beside it (same stem). Every file
    is written under a temporary name first and renamed at the end, so a failure leaves nothing half-written."""
    path = Path(path)
    check_texture_output(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh = textured.to_trimesh()
    staged: Dict[Path, bytes] = {}
    if path.suffix.lower() == ".glb":
        staged[path] = mesh.export(file_type="glb")
    else:
        from trimesh.exchange.obj import export_obj

        text, files = export_obj(mesh, include_normals=True, include_color=False, include_texture=True,
                                 return_texture=True, mtl_name=path.stem + ".mtl")
        for name, data in files.items():
            if name.lower().endswith(".mtl"):
                mtl = data.decode() if isinstance(data, bytes) else data
                for other in files:
                    if not other.lower().endswith(".mtl"):
                        mtl = mtl.replace(other, path.stem + Path(other).suffix)
                staged[path.with_suffix(".mtl")] = mtl.encode()
            else:
                staged[path.with_name(path.stem + Path(name).suffix)] = data
        staged[path] = text.encode()
    temporary = {}
    try:
        for target, data in staged.items():
            tmp = target.with_name(target.name + ".tmp")
            tmp.write_bytes(data)
            temporary[target] = tmp
        for target, tmp in temporary.items():
            tmp.replace(target)
    finally:
        for tmp in temporary.values():
            tmp.unlink(missing_ok=True)
    return list(staged)


def bake_picture(textured: TexturedMesh, report: BakeReport, path: Path, tile: int = 256) -> Path:
    """The atlas next to each view's weight map (white: that view gives the texel its whole colour)."""
    tiles = [cv2.resize(textured.image, (tile, tile), interpolation=cv2.INTER_AREA)]
    for m in report.weight_maps:
        small = cv2.resize(m, (tile, tile), interpolation=cv2.INTER_AREA)
        tiles.append(np.repeat(small[..., None], 3, -1))
    per_row = min(len(tiles), 5)
    while len(tiles) % per_row:
        tiles.append(np.ones_like(tiles[0]))
    rows = [np.concatenate(tiles[i:i + per_row], 1) for i in range(0, len(tiles), per_row)]
    write_image(Path(path), np.concatenate(rows, 0))
    return Path(path)


def write_bake_record(report: BakeReport, path: Path, extra: Optional[Dict[str, object]] = None) -> Path:
    record = {**report.summary(), **(extra or {})}
    Path(path).write_text(json.dumps(record, indent=2))
    return Path(path)



def texture_run_mesh(pipeline, mesh: trimesh.Trimesh, output: Path, size: int = 1024, fusion: str = "robust",
                     inconsistency: bool = False, progress: bool = True, harmonise_views: Optional[bool] = None,
                     max_faces: Optional[int] = MAX_TEXTURE_FACES):
    """Bake ``mesh`` from a loaded run's training views (field colour where none sees), write it to
    ``output`` (GLB or OBJ+MTL+PNG) with ``<stem>_bake.png`` (atlas | per-view weight maps) and
    ``<stem>_bake.json`` beside it; returns ``(TexturedMesh, BakeReport, written paths)``."""
    output = Path(output)
    check_texture_output(output)
    views = run_views(pipeline, inconsistency=inconsistency, progress=progress)
    textured, report = bake_texture(mesh, views, size=size, fusion=fusion, fallback=field_fallback(pipeline.model),
                                    progress=progress, harmonise_views=harmonise_views, max_faces=max_faces)
    written = write_textured_mesh(textured, output)
    written.append(bake_picture(textured, report, output.with_name(output.stem + "_bake.png")))
    written.append(write_bake_record(report, output.with_name(output.stem + "_bake.json"),
                                     {"texture_size": size, "fusion": fusion, "inconsistency_maps": inconsistency,
                                      "faces_extracted": len(mesh.faces), "faces_textured": len(textured.faces)}))
    return textured, report, written
