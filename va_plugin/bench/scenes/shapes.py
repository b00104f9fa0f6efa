"""Procedural benchmark objects: an SDF meshed by marching cubes plus an albedo texture of 3D position.

Every object fits in the box [-0.5, 0.5]^3 (SyncDreamer's normalisation), z up, and is chosen to stress
one or more hard cases of reconstruction: holes through the body (genus > 0), thin parts, concavities,
sharp edges, and color patterns with fine detail. Camera 0 of the rig looks from +x, so objects with a
front (the robot's face) face +x, as the conditioning view of a generator would see them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import trimesh

from va_plugin.bench.scenes.sdf import (
    SDF,
    intersect,
    length,
    mesh_from_sdf,
    sd_box,
    sd_capped_cylinder,
    sd_capsule,
    sd_cone_frustum,
    sd_polyline_tube,
    sd_sphere,
    sd_torus,
    subtract,
    to_local,
    union,
)
from va_plugin.errors import ConfigError

Texture = Callable[[np.ndarray], np.ndarray]


def _rgb(*values: float) -> np.ndarray:
    return np.array(values, dtype=np.float32)


def _mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per-point blend ``[n, 3]`` of colors ``a`` and ``b`` (each ``[3]`` or ``[n, 3]``) by ``t [n]``."""
    t = t.astype(np.float32)[:, None]
    return (1.0 - t) * a + t * b


def _checker(p: np.ndarray, size: float) -> np.ndarray:
    """1 / 0 on a 3D checkerboard of cell ``size`` ``[n]``."""
    return (np.floor(p / size).sum(-1) % 2).astype(np.float32)


def _where(mask: np.ndarray, color: np.ndarray, other: np.ndarray) -> np.ndarray:
    return np.where(mask[:, None], color, other)


# --- mug: genus 1, a concavity ---------------------------------------------------------------------------

def mug_sdf(p: np.ndarray) -> np.ndarray:
    """A mug: a hollow cylinder (a concavity) with a torus handle (genus 1)."""
    body = sd_capped_cylinder(p - [0.0, -0.06, 0.0], 0.26, 0.3)
    hollow = sd_capped_cylinder(p - [0.0, -0.06, 0.08], 0.21, 0.3)
    cup = subtract(body, hollow)
    ring = p - [0.0, 0.24, 0.0]
    handle = sd_torus(ring[:, [1, 2, 0]], 0.14, 0.045)  # a ring in the y-z plane
    handle = subtract(handle, ring[:, 1] + 0.07)  # the outer half, its ends sunk into the wall (genus 1)
    return union(cup, handle)


def mug_texture(p: np.ndarray) -> np.ndarray:
    """Red/cream horizontal bands on the body, a blue checker on the rim, a dark handle."""
    angle = np.arctan2(p[:, 1] + 0.06, p[:, 0])
    # Band and checker borders are kept off the flat top and bottom faces (z = +-0.3), where they would
    # flip with the marching-cubes noise.
    bands = (np.floor((p[:, 2] + 0.5) * 10.0 + 0.25) % 2).astype(np.float32)
    checker = ((np.floor(angle * 8 / np.pi) + np.floor((p[:, 2] + 0.5) * 20 + 0.25)) % 2).astype(np.float32)
    red, cream, blue = _rgb(0.8, 0.15, 0.1), _rgb(0.95, 0.9, 0.75), _rgb(0.15, 0.3, 0.8)
    color = _mix(cream, red, bands)
    color = _where(p[:, 2] > 0.2, _mix(cream, blue, checker), color)
    return _where(p[:, 1] > 0.22, _rgb(0.2, 0.2, 0.25), color)


# --- knot: genus 1, self-occluding thin strands ------------------------------------------------------------

KNOT_SAMPLES = 4000


@lru_cache(maxsize=1)
def _knot_curve() -> tuple[np.ndarray, np.ndarray]:
    """A (2, 3) torus knot (trefoil): samples ``[m, 3]`` and their curve parameters ``[m]`` in [0, 1)."""
    t = np.arange(KNOT_SAMPLES, dtype=np.float64) / KNOT_SAMPLES
    phi = 2.0 * np.pi * t
    radial = 0.27 + 0.13 * np.cos(3.0 * phi)
    curve = np.stack([radial * np.cos(2.0 * phi), radial * np.sin(2.0 * phi), 0.16 * np.sin(3.0 * phi)], -1)
    return curve.astype(np.float32), t.astype(np.float32)


def knot_sdf(p: np.ndarray) -> np.ndarray:
    return sd_polyline_tube(_knot_curve()[0], radius=0.055)(p)


def knot_texture(p: np.ndarray) -> np.ndarray:
    """Bands along the tube (36 per turn) with thin dark rings at their borders: detail a blur erases."""
    from scipy.spatial import cKDTree

    curve, t = _knot_curve()
    _, nearest = cKDTree(curve).query(p, k=1)
    s = t[nearest] * 36.0
    band = (np.floor(s) % 2).astype(np.float32)
    color = _mix(_rgb(0.95, 0.75, 0.1), _rgb(0.1, 0.55, 0.45), band)
    seam = np.abs(s - np.round(s)) < 0.08
    return _where(seam, _rgb(0.08, 0.08, 0.1), color)


# --- chair: thin legs, a slatted back (holes) ---------------------------------------------------------------

def chair_sdf(p: np.ndarray) -> np.ndarray:
    seat = sd_box(p - [0.0, 0.0, -0.06], [0.24, 0.24, 0.03], rounding=0.01)
    legs = union(*[sd_capped_cylinder(p - [sx * 0.2, sy * 0.2, -0.29], 0.022, 0.205)
                   for sx in (-1, 1) for sy in (-1, 1)])
    posts = union(*[sd_box(p - [-0.21, sy * 0.2, 0.2], [0.022, 0.022, 0.25]) for sy in (-1, 1)])
    rail = sd_box(p - [-0.21, 0.0, 0.43], [0.022, 0.22, 0.035])
    slats = union(*[sd_box(p - [-0.21, y, 0.2], [0.014, 0.022, 0.24]) for y in (-0.1, 0.0, 0.1)])
    return union(seat, legs, posts, rail, slats)


def chair_texture(p: np.ndarray) -> np.ndarray:
    """Wood grain (fine rings) on the frame, a red/white checker cushion on the seat top."""
    rings = 0.5 + 0.5 * np.sin(90.0 * length(p[:, [0, 2]] * [1.0, 0.3]) + 7.0 * p[:, 1])
    wood = _mix(_rgb(0.55, 0.33, 0.15), _rgb(0.78, 0.55, 0.3), rings)
    cushion = _mix(_rgb(0.95, 0.95, 0.92), _rgb(0.75, 0.1, 0.12), _checker(p[:, :2], 0.06))
    on_top = (p[:, 2] > -0.04) & (np.abs(p[:, 0]) < 0.18) & (np.abs(p[:, 1]) < 0.23)
    return _where(on_top, cushion, wood)


# --- bowl: a large concavity ---------------------------------------------------------------------------------

BOWL_CENTRE = np.array([0.0, 0.0, 0.28], dtype=np.float32)


def bowl_sdf(p: np.ndarray) -> np.ndarray:
    q = p - BOWL_CENTRE
    shell = np.abs(length(q) - 0.45) - 0.025
    shell = intersect(shell, q[:, 2])  # keep the lower half: open at the top
    foot = subtract(sd_capped_cylinder(p - [0.0, 0.0, -0.2], 0.2, 0.035),
                    sd_capped_cylinder(p - [0.0, 0.0, -0.23], 0.16, 0.04))
    return union(shell, foot)


def bowl_texture(p: np.ndarray) -> np.ndarray:
    """Blue rings inside, a grid of small dots outside, a dark rim line."""
    q = p - BOWL_CENTRE
    r = length(q)
    inside = r < 0.45
    rings = (np.sin(length(q[:, :2]) * 70.0) > 0.4).astype(np.float32)
    inner = _mix(_rgb(0.96, 0.95, 0.9), _rgb(0.15, 0.3, 0.75), rings)
    cell = 0.07
    centre = (np.floor(p / cell) + 0.5) * cell
    dots = (length(p - centre) < 0.018).astype(np.float32)
    outer = _mix(_rgb(0.85, 0.45, 0.2), _rgb(0.98, 0.95, 0.85), dots)
    color = _where(inside, inner, outer)
    return _where(q[:, 2] > -0.02, _rgb(0.1, 0.1, 0.12), color)


# --- blocks: sharp edges and corners, overhangs --------------------------------------------------------------

BLOCKS = [  # centre, half extents, yaw in degrees, checker colors; each sinks 1 cm into the one below
    ((0.0, 0.0, -0.32), (0.36, 0.24, 0.15), 0.0, (_rgb(0.9, 0.9, 0.88), _rgb(0.2, 0.35, 0.7))),
    ((0.04, 0.02, -0.04), (0.2, 0.2, 0.14), 30.0, (_rgb(0.95, 0.8, 0.2), _rgb(0.7, 0.15, 0.1))),
    ((0.12, -0.08, 0.25), (0.12, 0.22, 0.16), -20.0, (_rgb(0.2, 0.6, 0.3), _rgb(0.95, 0.95, 0.95))),
]


def blocks_sdf(p: np.ndarray) -> np.ndarray:
    return union(*[sd_box(to_local(p, c, yaw), half) for c, half, yaw, _ in BLOCKS])


def blocks_texture(p: np.ndarray) -> np.ndarray:
    """A checker of 5 cm cells in each block's own frame and colors, offset so no face lies on a cell border."""
    color = np.zeros((len(p), 3), np.float32)
    best = np.full(len(p), np.inf, np.float32)
    for centre, half, yaw, (a, b) in BLOCKS:
        local = to_local(p, centre, yaw)
        dist = np.abs(sd_box(local, half))  # the surface point belongs to the block it lies on
        closer = dist < best
        color[closer] = _mix(a, b, _checker(local[closer] + 1.025, 0.05))
        best = np.minimum(best, dist)
    return color


# --- lamp: a thin arm and a hollow shade -------------------------------------------------------------------

SHADE_CENTRE = (0.2, 0.0, 0.2)


def lamp_sdf(p: np.ndarray) -> np.ndarray:
    base = sd_capped_cylinder(p - [-0.2, 0.0, -0.44], 0.2, 0.035)
    lower_arm = sd_capsule(p, (-0.2, 0.0, -0.42), (-0.05, 0.0, 0.25), 0.02)
    upper_arm = union(sd_capsule(p, (-0.05, 0.0, 0.25), (0.2, 0.0, 0.42), 0.018),  # clear of the shade's rim,
                      sd_capsule(p, (0.2, 0.0, 0.42), (0.2, 0.0, 0.3), 0.018))    # then a stem down into it
    s = p - np.asarray(SHADE_CENTRE, dtype=p.dtype)
    outer = sd_cone_frustum(s, 0.2, 0.06, 0.12)
    inner = sd_cone_frustum(s - [0.0, 0.0, -0.035], 0.2 - 0.02, 0.06 - 0.02, 0.12)  # top plate 3.5 cm
    shade = subtract(outer, inner)  # open at the bottom: the inside is a concavity
    bulb = union(sd_sphere(s - [0.0, 0.0, -0.03], 0.055), sd_capsule(s, (0.0, 0.0, 0.11), (0.0, 0.0, 0.0), 0.02))
    return union(base, lower_arm, upper_arm, shade, bulb)


def lamp_texture(p: np.ndarray) -> np.ndarray:
    """Dark base with fine turned rings, grey arm, orange shade with thin stripes, pale inside, white bulb."""
    base_r = length(p[:, :2] - [-0.2, 0.0])
    base = _mix(_rgb(0.15, 0.15, 0.18), _rgb(0.35, 0.35, 0.4), (np.sin(base_r * 200.0) > 0).astype(np.float32))
    color = _where(p[:, 2] < -0.4, base, np.broadcast_to(_rgb(0.6, 0.62, 0.65), p.shape))
    s = p - np.asarray(SHADE_CENTRE, dtype=p.dtype)
    angle = np.arctan2(s[:, 1], s[:, 0])
    stripes = (np.sin(angle * 24.0) > 0.6).astype(np.float32)
    outside = _mix(_rgb(0.9, 0.45, 0.1), _rgb(0.55, 0.2, 0.05), stripes)
    inner = sd_cone_frustum(s - [0.0, 0.0, -0.035], 0.18, 0.04, 0.12)
    shell = subtract(sd_cone_frustum(s, 0.2, 0.06, 0.12), inner)
    on_shade = (np.abs(shell) < 0.01) & (length(s[:, :2]) > 0.025)  # not the stem through its top
    color = _where(on_shade, _where(inner < 0.005, _rgb(0.98, 0.92, 0.7), outside), color)
    bulb = length(s - [0.0, 0.0, -0.03]) < 0.06
    return _where(bulb, _rgb(1.0, 1.0, 0.95), color)


# --- robot: a character-like figure with thin limbs and a face --------------------------------------------

def robot_sdf(p: np.ndarray) -> np.ndarray:
    body = sd_box(p - [0.0, 0.0, -0.02], [0.12, 0.17, 0.18], rounding=0.03)
    head = sd_box(p - [0.0, 0.0, 0.27], [0.1, 0.12, 0.09], rounding=0.03)
    neck = sd_capped_cylinder(p - [0.0, 0.0, 0.17], 0.04, 0.03)
    antenna = union(sd_capsule(p, (0.0, 0.0, 0.35), (0.0, 0.0, 0.44), 0.01), sd_sphere(p - [0.0, 0.0, 0.455], 0.03))
    arms = union(*[sd_capsule(p, (0.0, sy * 0.19, 0.11), (0.1, sy * 0.3, -0.13), 0.03) for sy in (-1, 1)])
    hands = union(*[sd_sphere(p - [0.1, sy * 0.3, -0.16], 0.045) for sy in (-1, 1)])
    legs = union(*[sd_capsule(p, (0.0, sy * 0.08, -0.2), (0.0, sy * 0.1, -0.42), 0.035) for sy in (-1, 1)])
    feet = union(*[sd_box(p - [0.03, sy * 0.1, -0.45], [0.08, 0.05, 0.03], rounding=0.01) for sy in (-1, 1)])
    return union(body, head, neck, antenna, arms, hands, legs, feet)


def robot_texture(p: np.ndarray) -> np.ndarray:
    """Teal body with a chest panel of small buttons, a face (eyes, mouth) looking at +x, red antenna tip."""
    color = _mix(_rgb(0.2, 0.6, 0.65), _rgb(0.15, 0.45, 0.5), (np.floor(p[:, 2] * 30.0) % 2).astype(np.float32))
    front = p[:, 0] > 0.1
    panel = front & (np.abs(p[:, 1]) < 0.1) & (np.abs(p[:, 2] + 0.02) < 0.1)
    cell = 0.05
    centre = (np.floor(p[:, 1:] / cell) + 0.5) * cell
    buttons = length(p[:, 1:] - centre) < 0.013
    button_color = np.where((np.floor(p[:, 1:2] / cell) % 2) == 0, _rgb(0.9, 0.2, 0.15), _rgb(0.95, 0.85, 0.2))
    color = _where(panel, _where(buttons, button_color, _rgb(0.85, 0.87, 0.9)), color)
    face = (p[:, 0] > 0.09) & (p[:, 2] > 0.19) & (p[:, 2] < 0.36)
    eyes = (length(np.stack([np.abs(p[:, 1]) - 0.05, p[:, 2] - 0.3], -1)) < 0.025)
    mouth = (np.abs(p[:, 2] - 0.23) < 0.008) & (np.abs(p[:, 1]) < 0.06)
    color = _where(face, _where(eyes | mouth, _rgb(0.05, 0.05, 0.08), _rgb(0.9, 0.9, 0.88)), color)
    return _where(p[:, 2] > 0.43, _rgb(0.9, 0.1, 0.1), color)


@dataclass
class ProceduralObject:
    name: str
    description: str
    sdf: SDF
    texture: Texture


OBJECTS: dict[str, ProceduralObject] = {obj.name: obj for obj in [
    ProceduralObject("mug", "hollow cylinder with a ring handle: genus 1, a concavity, banded texture",
                     mug_sdf, mug_texture),
    ProceduralObject("knot", "trefoil torus-knot tube: genus 1, thin self-occluding strands, fine bands",
                     knot_sdf, knot_texture),
    ProceduralObject("chair", "chair with four thin legs and a slatted back (genus 4), wood grain, checker seat",
                     chair_sdf, chair_texture),
    ProceduralObject("bowl", "deep hemispherical bowl on a foot ring: a large concavity, thin rim, dots and rings",
                     bowl_sdf, bowl_texture),
    ProceduralObject("blocks", "three stacked boxes at different yaws: sharp edges, overhangs, fine checkers",
                     blocks_sdf, blocks_texture),
    ProceduralObject("lamp", "desk lamp: disk base, thin two-part arm, hollow cone shade open below",
                     lamp_sdf, lamp_texture),
    ProceduralObject("robot", "toy robot figure: thin limbs and antenna, a face and chest buttons as fine detail",
                     robot_sdf, robot_texture),
]}


def list_objects() -> list[tuple[str, str]]:
    """``(name, one-line description)`` of every procedural object."""
    return [(obj.name, obj.description) for obj in OBJECTS.values()]


def get_object(name: str) -> ProceduralObject:
    if name not in OBJECTS:
        raise ConfigError(f"unknown procedural object {name!r}; known: {', '.join(OBJECTS)}")
    return OBJECTS[name]


@lru_cache(maxsize=8)
def _cached_mesh(name: str, resolution: int) -> trimesh.Trimesh:
    return mesh_from_sdf(get_object(name).sdf, resolution=resolution)


def object_mesh(name: str, resolution: int = 160) -> trimesh.Trimesh:
    """The watertight marching-cubes mesh of a procedural object (a private copy: meshing is slow, so the
    result is cached)."""
    return _cached_mesh(name, resolution).copy()
