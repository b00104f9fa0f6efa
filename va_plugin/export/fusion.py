"""Color fusion across views, and the per-view color harmonisation that precedes it.

- ``mean``: the weighted average of the visible views' colors;
- ``robust``: the weighted medoid as a consensus, then reweighting rounds in which a view loses weight
  when it deviates from the consensus by more than its own noise.

Harmonisation fits one color gain per view and channel so that the views agree where they overlap.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from va_plugin.errors import VAError

FUSIONS = ("robust", "mean")
NOISE_FLOOR = 0.02
"""Smallest per-view noise (RGB distance) of the robust fusion, so a near-perfect view is not over-trusted."""
OUTLIER_SCALE = 2.0
"""A view deviating from the consensus by this many times its noise keeps 1/2 of its weight (Cauchy)."""
ROBUST_ROUNDS = 3
HARMONISE_ROUNDS = 8
"""Reweighting rounds of the per-view color fit (enough for a blob on part of a view to stop pulling)."""
FIT_WEIGHT = 0.25
"""Only texels both views of a pair see well (weight >= this: within 60 degrees of head-on, away from
silhouette edges) enter the color fit."""
RIDGE = 1e-3
"""Pull of each view's gains towards 1, per unit of the mean overlap weight of a view (it pins a view that
overlaps no other)."""
MAX_GAIN = 1.2
"""Largest color gain (and 1 / smallest) the harmonisation trusts; a view fitted beyond it is left as it
is (a far larger fit comes from misregistered overlaps, not from a cast)."""


def weighted_medoid(colors: np.ndarray, weights: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """Per point, the visible color with the least weighted sum of distances to the other visible
    colors: ``colors [m, n, 3]``, ``weights [m, n]`` -> ``[m, 3]``."""
    # with at most two visible views the medoid is the heavier one: no pairwise distances needed
    out = np.take_along_axis(colors, np.argmax(weights, axis=1)[:, None, None], axis=1)[:, 0].astype(np.float32)
    many = np.nonzero((weights > 0).sum(1) > 2)[0]
    for s in range(0, len(many), chunk):
        rows = many[s:s + chunk]
        c, w = torch.from_numpy(colors[rows]), torch.from_numpy(weights[rows])
        cost = torch.bmm(torch.cdist(c, c), w[:, :, None])[:, :, 0]  # [m, n]: weighted distance to the others
        cost[w <= 0] = torch.inf
        best = cost.argmin(1)
        out[rows] = c[torch.arange(len(rows)), best].numpy()
    return out


def view_noise(residual: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Each view's own noise ``[n]``: the median distance of its colors from the consensus where at least
    three views (else two) see a point, in [NOISE_FLOOR, twice the median over all views]."""
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


def fuse(colors: np.ndarray, weights: np.ndarray, mode: str = "robust"):
    """Fused color ``[m, 3]`` and the final per-view weights ``[m, n]`` (normalised per point; zero rows
    where no view sees the point) of ``colors [m, n, 3]`` seen with ``weights [m, n]``."""
    if mode not in FUSIONS:
        raise VAError(f"unknown fusion {mode!r}; use one of {', '.join(FUSIONS)}")
    colors, weights = np.ascontiguousarray(colors, np.float32), np.ascontiguousarray(weights, np.float32)
    c, w0 = torch.from_numpy(colors), torch.from_numpy(weights)
    w = w0
    if mode == "robust" and colors.shape[1] > 1:
        consensus = torch.from_numpy(weighted_medoid(colors, weights))
        residual = (c - consensus[:, None]).norm(dim=-1)
        noise = torch.from_numpy(view_noise(residual.numpy(), weights > 0))
        for round_ in range(ROBUST_ROUNDS):
            w = w0 / (1.0 + (residual / (OUTLIER_SCALE * noise)) ** 2)
            if round_ + 1 < ROBUST_ROUNDS:  # the last round's weights are the result
                consensus = torch.einsum("mn,mnc->mc", w, c) / w.sum(1, keepdim=True).clamp_min(1e-12)
                residual = (c - consensus[:, None]).norm(dim=-1)
    total = w.sum(1, keepdim=True)
    share = torch.where(total > 1e-12, w / total.clamp_min(1e-12), torch.zeros_like(w))
    return torch.einsum("mn,mnc->mc", share, c).numpy(), share.numpy()


def harmonise(colors: np.ndarray, weights: np.ndarray, reference: int = 0, rounds: int = HARMONISE_ROUNDS,
              max_gain: float | None = None):
    """Per-view color gains that make the views agree where they overlap: ``gains [n, 3]`` with view
    ``reference`` (the generator's conditioning view) fixed at 1.

    Per channel, a robust (Cauchy-reweighted) least-squares fit of ``a_k c_k = a_l c_l`` over texels two
    views both see well (weight sqrt(w_k w_l)), with a weak ridge towards 1. Gains only: with offsets the
    fit drifts on near-uniform colors. A view whose gains leave [1 / max_gain, max_gain] (default
    MAX_GAIN; ``inf`` keeps every fit) is kept at 1 and the others are fitted again."""
    max_gain = MAX_GAIN if max_gain is None else max_gain
    _m, n = weights.shape
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
            samples = [(k, l, w, colors[both, k, channel].astype(np.float64),
                        colors[both, l, channel].astype(np.float64)) for k, l, both, w in pairs]
            gains[keep, channel] = _fit_channel(samples, n, keep, ridge, rounds)
        wild = [k for k in keep if np.any(gains[k] > max_gain) or np.any(gains[k] < 1.0 / max_gain)]
        if not wild:
            break
        fixed.update(wild)
        gains[wild] = 1.0
        pairs = [p for p in pairs if p[0] not in wild and p[1] not in wild]  # nor does it pull the others
    return gains.astype(np.float32)


def _fit_channel(samples, n: int, keep: list[int], ridge: float, rounds: int) -> np.ndarray:
    """Gains of views ``keep`` for one color channel (the other views held at 1): iteratively reweighted
    least squares of ``a_k c_k - a_l c_l`` over ``samples``, one ``(k, l, weight, c_k, c_l)`` per pair
    of views of :func:`harmonise` (float64 arrays of the texels both see well)."""
    gains = np.ones(n)
    robust = [np.ones(len(w)) for _, _, w, _, _ in samples]
    products = [(ck * ck, cl * cl, ck * cl) for _, _, _, ck, cl in samples]  # the same in every round
    held = [i for i in range(n) if i not in keep]
    # the median of the residuals from a strided subsample of them all (the scale of the Cauchy weights
    # needs no more precision): which texels of each pair it picks
    lengths = [len(w) for _, _, w, _, _ in samples]
    total = sum(lengths)
    picked = np.arange(0, total, max(1, total // 65536))
    starts = np.cumsum([0] + lengths)
    picks = [picked[(picked >= a) & (picked < b)] - a for a, b in itertools.pairwise(starts)]
    for round_ in range(rounds + 1):
        normal = np.zeros((n, n))
        for (k, l, w, _, _), (kk, ll, kl), r in zip(samples, products, robust):
            wr = w * r
            # np.vdot: the same sum as np.dot, without the latter's thread hand-off on 1-D arrays
            normal[k, k] += float(np.vdot(wr, kk))
            normal[l, l] += float(np.vdot(wr, ll))
            normal[k, l] -= float(np.vdot(wr, kl))
            normal[l, k] = normal[k, l]
        normal[np.arange(n), np.arange(n)] += ridge
        rhs = np.full(n, ridge) - normal[:, held].sum(1)  # ridge towards 1; the held views' gains are 1
        gains[keep] = np.linalg.solve(normal[np.ix_(keep, keep)], rhs[keep])
        if round_ == rounds:
            break  # the last round's weights would go unused
        residuals = [gains[k] * ck - gains[l] * cl for k, l, _, ck, cl in samples]
        sample = np.abs(np.concatenate([res[pick] for res, pick in zip(residuals, picks)]))
        scale = max(1.4826 * float(np.median(sample)), 1e-3)
        robust = [1.0 / (1.0 + (res / (OUTLIER_SCALE * scale)) ** 2) for res in residuals]
    return gains[keep]


def apply_harmonisation(colors: np.ndarray, weights: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``colors [m, n, 3]`` with each view's gains applied where it sees the point (clipped to [0, 1])."""
    out = np.multiply(colors, gains[None].astype(np.float32), dtype=np.float32)
    np.clip(out, 0.0, 1.0, out=out)
    np.copyto(out, colors, where=(weights <= 0)[..., None])
    return out
