"""Camera checks: known 3D points projected into each generator rig land where the generator's own
convention puts them (SyncDreamer's camera-16.pkl, Zero123++/InstantMesh's formulas, Wonder3D's
fixed poses and orthographic rays)."""

import math
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from va_plugin.cameras import ORTHOGRAPHIC, opengl_to_opencv
from va_plugin.data import rigs
from va_plugin.errors import ConfigError

SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
RIG_PKL = SHARED_DATA / "syncdreamer_rig" / "camera-16.pkl"

POINTS = torch.tensor([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [-0.25, 0.4, -0.3], [0.5, 0.5, 0.5]])


def world_to_pixels(K: np.ndarray, w2c: np.ndarray, points: torch.Tensor) -> np.ndarray:
    """``K @ (R X + t)`` then divide by depth: SyncDreamer's projection, integer pixel centres."""
    cam = points.numpy() @ w2c[:3, :3].T + w2c[:3, 3]
    uvw = cam @ K.T
    return uvw[:, :2] / uvw[:, 2:]


@pytest.mark.skipif(not RIG_PKL.is_file(), reason=f"SyncDreamer rig file absent: {RIG_PKL}")
def test_syncdreamer_rig_matches_camera_16_pkl():
    with open(RIG_PKL, "rb") as handle:
        K, azimuths, elevations, distances, poses = pickle.load(handle)
    rig = rigs.syncdreamer_rig(256, pixel_offset=0.0)
    assert np.allclose(np.degrees(azimuths), [k * 22.5 for k in range(16)], atol=1e-4)
    assert np.allclose(np.degrees(elevations), 30.0, atol=1e-4) and np.allclose(distances, 1.5)
    for k in range(16):
        expected = world_to_pixels(np.asarray(K), np.asarray(poses[k]), POINTS)
        uv, _ = rig.project(POINTS, k)
        assert np.allclose(uv.numpy(), expected, atol=1e-3), k
    # the parser samples pixel centres at +0.5 (Blender renders): the same points sit half a pixel up-left
    shifted = rigs.syncdreamer_rig(256, pixel_offset=0.5)
    uv, _ = shifted.project(POINTS, 3)
    assert np.allclose(uv.numpy(), world_to_pixels(np.asarray(K), np.asarray(poses[3]), POINTS) - 0.5, atol=1e-3)


def test_syncdreamer_hand_computed_directions():
    rig = rigs.syncdreamer_rig(256, pixel_offset=0.0)
    # camera 0 sits on +x looking at the origin, z up: +y appears to the right, +z above the centre
    uv, _depth = rig.project(torch.tensor([[0.0, 0.2, 0.0], [0.0, 0.0, 0.2]]), 0)
    assert uv[0, 0] > 128.0 and abs(float(uv[0, 1]) - 128.0) < 1e-3
    assert uv[1, 1] < 128.0 and abs(float(uv[1, 0]) - 128.0) < 1e-3
    # camera 4 (azimuth 90) sits on +y: there +x appears to the left
    uv, _ = rig.project(torch.tensor([[0.2, 0.0, 0.0]]), 4)
    assert uv[0, 0] < 128.0
    # elevation: camera k is at height 1.5 sin(30 deg) = 0.75
    assert torch.allclose(rig.centers[:, 2], torch.full((16,), 0.75), atol=1e-5)
    assert rigs.input_view_ids(4) == [0, 4, 8, 12] and rigs.input_view_ids(8) == [0, 2, 4, 6, 8, 10, 12, 14]
    assert len(rigs.input_view_ids(12)) == 12 and rigs.input_view_ids(16) == list(range(16))


@pytest.mark.parametrize("version, elevations, fov", [("v1.1", (30, -20), 2 * math.degrees(math.atan(16 / 35))),
                                                      ("v1.2", (20, -10), 30.0)])
def test_zero123pp_rig_follows_instantmesh_formula(version, elevations, fov):
    rig = rigs.zero123pp_rig(version, 320, radius=4.0)
    for k, azimuth in enumerate((30, 90, 150, 210, 270, 330)):
        el, az = math.radians(elevations[k % 2]), math.radians(azimuth)
        eye = 4.0 * torch.tensor([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        assert torch.allclose(rig.centers[k], eye, atol=1e-5)
        uv, depth = rig.project(torch.zeros(1, 3), k)
        assert torch.allclose(uv, torch.tensor([[159.5, 159.5]]), atol=1e-3) and float(depth) == pytest.approx(4.0)
    # a point on the image's top edge is fov / 2 above the optical axis
    half = math.radians(fov / 2)
    c2w = rig.c2w[0]
    point = c2w[:, 3] + 4.0 * (c2w[:, 2] - math.tan(half) * c2w[:, 1])
    uv, _ = rig.project(point[None], 0)
    assert float(uv[0, 1]) == pytest.approx(-0.5, abs=1e-3)
    with pytest.raises(ConfigError, match=r"v1\.1, v1\.2"):
        rigs.zero123pp_rig("v2")


# Wonder3D's fixed world-to-camera poses (OpenGL camera axes), instant-nsr-pl/datasets/fixed_poses:
# front at -y, right at +x, front_right between them; rows are the camera axes in its world.
WONDER3D_W2C_ROTATIONS = {
    "front": [[1, 0, 0], [0, 0, 1], [0, -1, 0]],
    "front_right": [[0.70710677, 0.70710683, 0], [0, 0, 1], [0.70710683, -0.70710683, 0]],
    "right": [[0, 1, 0], [0, 0, 1], [1, 0, 0]],
    "left": [[0, -1, 0], [0, 0, 1], [-1, 0, 0]],
}


def test_wonder3d_relative_poses_match_fixed_poses():
    rig = rigs.wonder3d_rig(256)
    names = [v for v, _ in rigs.WONDER3D_VIEWS]
    assert rig.camera_type == ORTHOGRAPHIC
    gl = opengl_to_opencv(rig.c2w)  # OpenGL-axes camera-to-world
    w2c = {name: gl[k, :, :3].T.double() for k, name in enumerate(names)}
    theirs = {name: torch.tensor(r, dtype=torch.float64) for name, r in WONDER3D_W2C_ROTATIONS.items()}
    # relative rotations do not depend on where each convention puts its world axes
    for name in ("front_right", "right", "left"):
        ours = w2c[name] @ w2c["front"].T
        expected = theirs[name] @ theirs["front"].T
        assert torch.allclose(ours, expected, atol=1e-5), name


def test_wonder3d_orthographic_projection():
    rig = rigs.wonder3d_rig(256)
    # front camera on +x looking at -x: world +y is to the right, +z up; 256 px span 1.35 world units
    uv, _depth = rig.project(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.675, 0.0], [0.0, 0.0, 0.675], [-0.3, 0.1, 0.0]]), 0)
    assert torch.allclose(uv[0], torch.tensor([127.5, 127.5]))
    assert torch.allclose(uv[1], torch.tensor([255.5, 127.5]), atol=1e-4)
    assert torch.allclose(uv[2], torch.tensor([127.5, -0.5]), atol=1e-4)
    assert float(uv[3, 0]) == pytest.approx(127.5 + 0.1 * 256 / 1.35, abs=1e-3)
    # Wonder3D's own rays: origin (((i + 0.5) / W - 0.5) * s, ...) in the camera plane, direction +z
    origins, directions = rig.generate_rays(torch.tensor([0]), torch.tensor([10.0]), torch.tensor([200.0]))
    assert torch.allclose(directions, torch.tensor([[-1.0, 0.0, 0.0]]), atol=1e-6)
    x = ((200 + 0.5) / 256 - 0.5) * 1.35
    y = ((10 + 0.5) / 256 - 0.5) * 1.35
    assert torch.allclose(origins[0, 1:], torch.tensor([x, -y]), atol=1e-5)
    # the right view (azimuth 90) sees the front camera's +y direction head-on
    assert torch.allclose(rig.c2w[2, :, 2], torch.tensor([0.0, -1.0, 0.0]), atol=1e-6)
