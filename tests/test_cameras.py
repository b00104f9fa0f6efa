import math

import pytest
import torch

from va_plugin.cameras import ORTHOGRAPHIC, Cameras, look_at, opengl_to_opencv
from va_plugin.errors import DataError


def identity_camera(**kw):
    c2w = torch.eye(4)[:3][None]
    return Cameras(c2w, 100.0, 100.0, 50.0, 40.0, 100, 80, **kw)


def test_center_pixel_ray_points_along_plus_z():
    cam = identity_camera(pixel_offset=0.5)
    # pixel (row 39.5 - 0.5 -> 39.5?) : the principal point cx=50, cy=40 sits at pixel index 49.5, 39.5
    origins, dirs = cam.generate_rays(torch.tensor([0]), torch.tensor([39.5]), torch.tensor([49.5]))
    assert torch.allclose(dirs, torch.tensor([[0.0, 0.0, 1.0]]), atol=1e-6)
    assert torch.allclose(origins, torch.zeros(1, 3))


def test_hand_computed_projection_round_trip():
    cam = identity_camera(pixel_offset=0.0)
    point = torch.tensor([[0.2, -0.1, 2.0]])
    uv, depth = cam.project(point, 0)
    # u = fx X/Z + cx = 100 * 0.1 + 50 = 60; v = 100 * -0.05 + 40 = 35
    assert torch.allclose(uv, torch.tensor([[60.0, 35.0]]))
    assert float(depth) == pytest.approx(2.0)
    _, d = cam.generate_rays(torch.tensor([0]), uv[:, 1], uv[:, 0])
    assert torch.allclose(d, point / point.norm(), atol=1e-6)


def test_orthographic_rays_are_parallel_and_offset():
    cam = Cameras(torch.eye(4)[:3][None], 10.0, 10.0, 5.0, 5.0, 10, 10, camera_type=ORTHOGRAPHIC, pixel_offset=0.0)
    o, d = cam.generate_rays(torch.tensor([0, 0]), torch.tensor([5.0, 5.0]), torch.tensor([5.0, 9.0]))
    assert torch.allclose(d, torch.tensor([[0.0, 0.0, 1.0]] * 2))
    assert torch.allclose(o[1], torch.tensor([0.4, 0.0, 0.0]))
    uv, _ = cam.project(o + d, 0)
    assert torch.allclose(uv, torch.tensor([[5.0, 5.0], [9.0, 5.0]]), atol=1e-5)


def test_opengl_conversion_flips_y_and_z():
    gl = torch.eye(4)[:3][None]
    cv = opengl_to_opencv(gl)
    assert torch.allclose(cv[0, :, :3], torch.diag(torch.tensor([1.0, -1.0, -1.0])))
    assert torch.allclose(opengl_to_opencv(cv), gl)


def test_look_at_faces_target_with_z_up():
    eye = torch.tensor([[1.5, 0.0, 0.0]])
    c2w = look_at(eye, torch.zeros(1, 3), torch.tensor([0.0, 0.0, 1.0]))
    assert torch.allclose(c2w[0, :, 2], torch.tensor([-1.0, 0.0, 0.0]))  # forward
    assert c2w[0, 2, 1] < 0  # image "down" points to world -z


def test_scaled_cameras_project_consistently():
    cam = identity_camera(pixel_offset=0.5)
    half = cam.scaled(0.5)
    point = torch.tensor([[0.1, 0.05, 1.0]])
    uv_full, _ = cam.project(point, 0)
    uv_half, _ = half.project(point, 0)
    assert half.width == 50 and half.height == 40
    assert torch.allclose((uv_full + 0.5) * 0.5, uv_half + 0.5, atol=1e-5)


@pytest.mark.parametrize("bad, message", [
    (torch.full((1, 3, 4), float("nan")), "NaN"),
    (torch.cat([2 * torch.eye(3), torch.zeros(3, 1)], 1)[None], "orthonormal"),
    (torch.cat([torch.diag(torch.tensor([1.0, 1.0, -1.0])), torch.zeros(3, 1)], 1)[None], "reflection"),
])
def test_bad_poses_are_refused(bad, message):
    with pytest.raises(DataError, match=message):
        Cameras(bad, 1.0, 1.0, 0.0, 0.0, 2, 2)


def test_syncdreamer_rig_camera_zero_position():
    from va_plugin.bench.scenes.rig import syncdreamer_rig

    rig = syncdreamer_rig()
    assert torch.allclose(rig.centers[0], torch.tensor([1.299, 0.0, 0.75]), atol=1e-3)
    # the origin projects to the principal point (128, 128) in every view
    for i in range(len(rig)):
        uv, depth = rig.project(torch.zeros(1, 3), i)
        assert torch.allclose(uv, torch.tensor([[128.0, 128.0]]), atol=1e-3)
        assert float(depth) == pytest.approx(1.5, abs=1e-4)
    assert math.isclose(float(rig.fx[0]), 280.0)


@pytest.mark.parametrize("camera_type", ["perspective", ORTHOGRAPHIC])
def test_rays_of_one_view_equal_the_per_ray_path(camera_type):
    # a tilted camera away from the origin: every column of the rotation matters
    c2w = look_at(torch.tensor([[1.2, -0.7, 2.1], [-0.5, 1.5, 0.4]]), torch.zeros(2, 3), torch.tensor([0.0, 0.0, 1.0]))
    cam = Cameras(c2w, 90.0, 110.0, 31.0, 25.0, 64, 48, camera_type=camera_type)
    g = torch.Generator().manual_seed(0)
    rows, cols = torch.rand(500, generator=g) * 48, torch.rand(500, generator=g) * 64
    one = cam.generate_rays(1, rows, cols)
    per_ray = cam.generate_rays(torch.ones(500, dtype=torch.long), rows, cols)
    for a, b in zip(one, per_ray):
        assert a.shape == b.shape == (500, 3) and a.is_contiguous()
        assert torch.equal(a, b)
    # against the rotation applied as a matrix to the camera-frame offsets (x, y, 1) or (x, y, 0)
    x, y = (cols + 0.5 - 31.0) / 90.0, (rows + 0.5 - 25.0) / 110.0
    local = torch.stack([x, y, torch.ones_like(x) if camera_type == "perspective" else torch.zeros_like(x)], -1)
    turned = local @ c2w[1, :, :3].T
    if camera_type == "perspective":
        assert torch.allclose(one[1], turned / turned.norm(dim=-1, keepdim=True), atol=1e-6)
        assert torch.allclose(one[0], c2w[1, :, 3].expand(500, 3))
    else:
        assert torch.allclose(one[0], c2w[1, :, 3] + turned, atol=1e-6)
        assert torch.allclose(one[1], c2w[1, :, 2].expand(500, 3))
