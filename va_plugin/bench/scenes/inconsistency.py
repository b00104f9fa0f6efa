"""Controlled, seeded view inconsistency of the kinds multi-view generators produce.

Kinds (switchable separately):

* ``geometric``: a smooth low-frequency displacement of the mesh (rendered sources) or of the image
  (image sources).
* ``appearance``: a slight blur, a per-view color gain and offset, and a few hallucinated texture
  blobs, on the object only.
* ``pose``: the view seen from a slightly wrong orbit position; the written camera stays nominal.

Levels 0-3 scale one set of random draws per view (0: the clean render). Every draw comes from
``(seed, rig view, kind)``, independent of the view count and the other kinds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from va_plugin.errors import ConfigError

KINDS = ("geometric", "appearance", "pose")
LEVELS = (0, 1, 2, 3)
LEVEL_SCALE = {0: 0.0, 1: 0.5, 2: 1.0, 3: 2.0}
_KIND_STREAM = {"geometric": 1, "appearance": 2, "pose": 3}


@dataclass(frozen=True)
class Amplitudes:
    """Level-2 sizes: all three kinds together score about PSNR 25 dB and LPIPS 0.07 against the clean
    render at 256 px, like real SyncDreamer views."""

    displacement: float = 0.0065      # RMS vertex displacement, world units (objects are 1 unit large)
    cycles: tuple[float, float] = (0.5, 1.5)  # spatial frequency range of the field, cycles per unit
    modes: int = 4                    # sine modes summed in the field
    orbit_deg: float = 0.8            # std of the azimuth and elevation errors
    roll_deg: float = 0.5             # std of the roll about the optical axis
    gain: float = 0.04                # std of the per-channel color gain around 1
    offset: float = 0.015             # std of the per-channel color offset
    blobs: int = 3                    # hallucinated blobs per view
    blob_opacity: float = 0.8
    blob_radius: tuple[float, float] = (0.04, 0.08)  # as a fraction of the image side
    blur_px: float = 1.6              # gaussian sigma of the generator's softness, pixels at 256 px


AMPLITUDES = Amplitudes()


@dataclass
class InconsistencySpec:
    """Which kinds, how strong, and which input views stay clean."""

    kinds: tuple[str, ...] = KINDS
    level: int = 2
    seed: int = 42
    clean_views: tuple[int, ...] = (0,)

    def __post_init__(self) -> None:
        self.kinds = parse_kinds(self.kinds)
        self.level = parse_level(self.level)

    @property
    def active(self) -> bool:
        return self.level > 0 and len(self.kinds) > 0

    def perturbs(self, view: int) -> bool:
        return self.active and view not in self.clean_views


def parse_kinds(kinds) -> tuple[str, ...]:
    """Kinds from a comma-separated string or a sequence, in canonical order; ``none`` or empty: no kind."""
    items = [k.strip() for k in kinds.split(",")] if isinstance(kinds, str) else [str(k).strip() for k in kinds]
    items = [k for k in items if k and k != "none"]
    unknown = [k for k in items if k not in KINDS]
    if unknown:
        raise ConfigError(f"unknown inconsistency kind(s) {', '.join(map(repr, unknown))}; "
                          f"use a comma-separated subset of {','.join(KINDS)} (or none)")
    return tuple(k for k in KINDS if k in items)


def parse_level(level) -> int:
    try:
        value = int(level)
    except (TypeError, ValueError):
        value = -1
    if value not in LEVELS or str(level).strip() not in {str(v) for v in LEVELS}:
        raise ConfigError(f"inconsistency level must be one of {', '.join(map(str, LEVELS))}, got {level!r}")
    return value


def stream(seed: int, view: int, kind: str) -> np.random.Generator:
    """The random stream of one kind for one rig view."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(view), _KIND_STREAM[kind]]))


@dataclass
class DisplacementField:
    """A smooth random field ``d(x) = sum_k a_k sin(2 pi f_k . x + phi_k)`` in ``dim`` dimensions."""

    frequencies: np.ndarray  # [m, dim] cycles per unit
    phases: np.ndarray  # [m]
    amplitudes: np.ndarray  # [m, dim], scaled so the field's RMS over random positions is ``rms``

    @staticmethod
    def draw(rng: np.random.Generator, dim: int, rms: float, amp: Amplitudes = AMPLITUDES) -> DisplacementField:
        directions = rng.normal(size=(amp.modes, dim))
        directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
        frequencies = directions * rng.uniform(*amp.cycles, size=(amp.modes, 1))
        phases = rng.uniform(0.0, 2.0 * np.pi, size=amp.modes)
        amplitudes = rng.normal(size=(amp.modes, dim))
        amplitudes *= rms / np.sqrt(0.5 * (amplitudes**2).sum())  # E[sin^2] = 1/2
        return DisplacementField(frequencies, phases, amplitudes)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Displacements ``[n, dim]`` at ``points [n, dim]``."""
        waves = np.sin(2.0 * np.pi * points.astype(np.float64) @ self.frequencies.T + self.phases)
        return (waves @ self.amplitudes).astype(np.float32)


@dataclass
class Blob:
    """A hallucinated texture patch: plausible colors taken from elsewhere on the object, in a blotchy
    pattern, inside a ragged soft disc."""

    where: float                  # quantile in [0, 1) of the object's pixels (row-major): the centre
    radius: float                 # fraction of the image side
    sources: np.ndarray           # [2] quantiles of object pixels whose colors the patch paints with
    tint: np.ndarray              # [2, 3] shifts of those colors
    waves: np.ndarray             # [3, 3] per wave: angle, period (fraction of the radius), phase
    ragged: np.ndarray            # [3] amplitude, lobes, phase of the outline's wobble

    @staticmethod
    def draw(rng: np.random.Generator, amp: Amplitudes = AMPLITUDES) -> Blob:
        waves = np.stack([rng.uniform(0.0, np.pi, 3), rng.uniform(0.4, 1.0, 3), rng.uniform(0, 2 * np.pi, 3)], -1)
        return Blob(where=float(rng.random()), radius=float(rng.uniform(*amp.blob_radius)),
                    sources=rng.random(2), tint=rng.normal(scale=0.08, size=(2, 3)).astype(np.float32),
                    waves=waves,
                    ragged=np.array([rng.uniform(0.1, 0.3), rng.integers(2, 6), rng.uniform(0, 2 * np.pi)]))


@dataclass
class ViewPerturbation:
    """The perturbation of one input view at one level; a kind that is off is None."""

    view: int
    level: int
    displacement: DisplacementField | None = None   # world units, 3-d (meshes) and 2-d (images)
    displacement_2d: DisplacementField | None = None
    orbit_deg: tuple[float, float, float] | None = None  # azimuth, elevation, roll errors
    gain: np.ndarray | None = None                  # [3]
    offset: np.ndarray | None = None                # [3]
    blobs: list[Blob] = field(default_factory=list)
    blob_opacity: float = 0.0
    blur: float = 0.0                                  # sigma as a fraction of the image side

    def summary(self) -> dict[str, object]:
        """JSON-ready sizes of what was drawn (the measured image error is reported separately)."""
        out: dict[str, object] = {}
        if self.displacement is not None:
            out["displacement_rms"] = _round(np.sqrt(0.5 * (self.displacement.amplitudes**2).sum()))
        if self.orbit_deg is not None:
            out["pose_error_deg"] = dict(zip(("azimuth", "elevation", "roll"), map(_round, self.orbit_deg)))
        if self.gain is not None:
            out["color_gain"] = [_round(g) for g in self.gain]
            out["color_offset"] = [_round(o) for o in self.offset]
            out["blobs"] = len(self.blobs)
            out["blur_sigma_px_at_256"] = _round(self.blur * 256.0)
        return out


def _round(value: float, digits: int = 4) -> float:
    return round(float(value), digits)


def draw_perturbation(spec: InconsistencySpec, view: int, amp: Amplitudes | None = None) -> ViewPerturbation:
    """The perturbation of rig view ``view`` under ``spec`` (an empty one for clean views)."""
    amp = AMPLITUDES if amp is None else amp
    out = ViewPerturbation(view, spec.level)
    if not spec.perturbs(view):
        return out
    s = LEVEL_SCALE[spec.level]
    if "geometric" in spec.kinds:
        rng = stream(spec.seed, view, "geometric")
        out.displacement = DisplacementField.draw(rng, 3, amp.displacement * s, amp)
        out.displacement_2d = DisplacementField.draw(rng, 2, amp.displacement * s, amp)
    if "pose" in spec.kinds:
        rng = stream(spec.seed, view, "pose")
        errors = rng.normal(size=3) * [amp.orbit_deg, amp.orbit_deg, amp.roll_deg] * s
        out.orbit_deg = tuple(float(e) for e in errors)
    if "appearance" in spec.kinds:
        rng = stream(spec.seed, view, "appearance")
        out.gain = (1.0 + rng.normal(size=3) * amp.gain * s).astype(np.float32)
        out.offset = (rng.normal(size=3) * amp.offset * s).astype(np.float32)
        # Draw the most blobs any level uses, so that a level takes a prefix of the same list.
        pool = [Blob.draw(rng, amp) for _ in range(round(amp.blobs * LEVEL_SCALE[max(LEVELS)]))]
        out.blobs = pool[:round(amp.blobs * s)]
        out.blob_opacity = amp.blob_opacity * min(1.0, s)
        out.blur = amp.blur_px / 256.0 * s * float(rng.uniform(0.7, 1.3))
    return out


# --- image-space operations ---------------------------------------------------------------------------------

def _blob_weight(blob: Blob, centre: tuple[float, float], height: int, width: int) -> np.ndarray:
    """Soft, ragged disc ``[H, W]`` in [0, 1] around ``centre`` (row, col)."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    dy, dx = rows - centre[0], cols - centre[1]
    radius = blob.radius * max(height, width)
    wobble = 1.0 + blob.ragged[0] * np.sin(blob.ragged[1] * np.arctan2(dy, dx) + blob.ragged[2])
    r = np.sqrt(dy * dy + dx * dx) / (radius * wobble)
    return np.clip(1.0 - r * r, 0.0, 1.0) ** 2


def _blob_color(blob: Blob, palette: np.ndarray, height: int, width: int) -> np.ndarray:
    """Blotchy two-color texture ``[H, W, 3]``; ``palette [2, 3]`` are the borrowed colors."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    radius = blob.radius * max(height, width)
    field = np.zeros((height, width), np.float32)
    for angle, period, phase in blob.waves:
        field += np.sin(2.0 * np.pi * (cols * np.cos(angle) + rows * np.sin(angle)) / (period * radius) + phase)
    t = (0.5 + 0.5 * np.tanh(2.0 * field))[:, :, None]
    colors = np.clip(palette + blob.tint, 0.0, 1.0)
    return (1.0 - t) * colors[0] + t * colors[1]


def soften(rgba: np.ndarray, sigma_px: float) -> np.ndarray:
    """The color ``[H, W, 3]`` of an RGBA image blurred inside the object (premultiplied, so the
    background does not bleed in); alpha is left to the caller."""
    if sigma_px <= 0:
        return rgba[:, :, :3]
    premultiplied = np.concatenate([rgba[:, :, :3] * rgba[:, :, 3:], rgba[:, :, 3:]], -1)
    blurred = cv2.GaussianBlur(premultiplied, (0, 0), sigmaX=sigma_px, borderType=cv2.BORDER_CONSTANT)
    weight = blurred[:, :, 3:]
    return np.where(weight > 1e-6, blurred[:, :, :3] / np.maximum(weight, 1e-6), rgba[:, :, :3]).astype(np.float32)


def apply_appearance(rgba: np.ndarray, p: ViewPerturbation) -> np.ndarray:
    """Color gain/offset and texture blobs on the object of a straight-alpha image ``[H, W, 4]``."""
    if p.gain is None:
        return rgba
    h, w = rgba.shape[:2]
    alpha = rgba[:, :, 3:]
    on_object = (alpha > 0).astype(np.float32)
    rgb = soften(rgba, p.blur * max(h, w))
    rgb = np.clip(rgb * p.gain + p.offset, 0.0, 1.0) * on_object + rgba[:, :, :3] * (1 - on_object)
    pixels = np.argwhere(alpha[:, :, 0] > 0.5)

    def pick(quantile: float) -> np.ndarray:
        return pixels[min(int(quantile * len(pixels)), len(pixels) - 1)]

    for blob in p.blobs:
        if len(pixels) == 0:
            break
        palette = np.stack([rgb[tuple(pick(q))] for q in blob.sources])
        weight = (p.blob_opacity * _blob_weight(blob, tuple(pick(blob.where)), h, w))[:, :, None] * on_object
        rgb = rgb * (1.0 - weight) + _blob_color(blob, palette, h, w) * weight
    return np.concatenate([rgb, alpha], -1).astype(np.float32)


def identity_map(height: int, width: int) -> np.ndarray:
    """Pixel coordinates ``[H, W, 2]`` (col, row) of every pixel: the map of no warp."""
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    return np.stack([cols, rows], -1)


def displacement_map(displacement: DisplacementField, height: int, width: int, pixels_per_unit: float
                     ) -> np.ndarray:
    """Where each output pixel samples the input ``[H, W, 2]``: itself plus the field in pixels."""
    grid = identity_map(height, width)
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0], np.float32)
    world = ((grid - centre) / pixels_per_unit).reshape(-1, 2)
    return grid + displacement(world).reshape(height, width, 2) * pixels_per_unit


def compose_maps(outer: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """The map of sampling with ``inner`` after ``outer`` (``outer(inner(p))``), both ``[H, W, 2]``."""
    return np.stack([cv2.remap(np.ascontiguousarray(outer[:, :, c]), inner[:, :, 0], inner[:, :, 1],
                               cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for c in range(2)], -1)


def remap_rgba(rgba: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """Resample a straight-alpha image ``[H, W, 4]`` at ``coords [H, W, 2]`` (premultiplied, so the color of
    the background never bleeds into the object's edge)."""
    premultiplied = np.concatenate([rgba[:, :, :3] * rgba[:, :, 3:], rgba[:, :, 3:]], -1).astype(np.float32)
    out = cv2.remap(premultiplied, coords[:, :, 0].astype(np.float32), coords[:, :, 1].astype(np.float32),
                    cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    alpha = np.clip(out[:, :, 3:], 0.0, 1.0)
    rgb = np.where(alpha > 0, out[:, :, :3] / np.maximum(alpha, 1e-6), 0.0)
    return np.concatenate([np.clip(rgb, 0.0, 1.0), alpha], -1).astype(np.float32)


def perturbed_vertices(vertices: np.ndarray, p: ViewPerturbation) -> np.ndarray:
    """Mesh vertices ``[v, 3]`` moved by the view's displacement field (unchanged without one)."""
    if p.displacement is None:
        return vertices
    return (vertices + p.displacement(vertices)).astype(np.float32)


def mean_of(values: Sequence[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return _round(np.mean(present)) if present else None
