import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from va_plugin.data.datamanager import DataManager, DataManagerConfig
from va_plugin.data.dataparsers import detect_format, resolve_dataparser
from va_plugin.data.dataparsers.transforms import TransformsDataParserConfig
from va_plugin.data.images import write_image
from va_plugin.errors import DataError


def write_scene(root: Path, n=2, size=(8, 6), rgba=True, camera_angle_x=None, split=True):
    root.mkdir(parents=True, exist_ok=True)
    frames = []
    for i in range(n):
        image = np.zeros((size[1], size[0], 4 if rgba else 3), np.float32)
        image[..., 0] = 1.0
        if rgba:
            image[: size[1] // 2, :, 3] = 1.0  # top half opaque red, bottom half transparent
        write_image(root / f"r_{i}.png", image)
        matrix = np.eye(4)
        matrix[:3, 3] = [0.0, 0.0, 2.0 + i]
        frames.append({"file_path": f"./r_{i}", "transform_matrix": matrix.tolist()})
    meta = {"frames": frames}
    if camera_angle_x is not None:
        meta["camera_angle_x"] = camera_angle_x
    else:
        meta.update({"fl_x": 10.0, "fl_y": 11.0, "cx": 4.0, "cy": 3.0, "w": size[0], "h": size[1]})
    name = "transforms_train.json" if split else "transforms.json"
    (root / name).write_text(json.dumps(meta))
    return root


def parse(root, **kw):
    return TransformsDataParserConfig(data=root, **kw).setup().get_outputs("train")


def test_intrinsics_poses_and_alpha(tmp_path):
    out = parse(write_scene(tmp_path / "s"))
    assert out.images.shape == (2, 6, 8, 3) and out.masks.shape == (2, 6, 8, 1)
    assert torch.allclose(out.cameras.fx, torch.tensor([10.0, 10.0]))
    assert torch.allclose(out.cameras.fy, torch.tensor([11.0, 11.0]))
    # OpenGL -> OpenCV: the camera's z axis flips
    assert torch.allclose(out.cameras.c2w[0, :, 2], torch.tensor([0.0, 0.0, -1.0]))
    assert torch.allclose(out.cameras.centers[1], torch.tensor([0.0, 0.0, 3.0]))
    # transparent pixels are composited on white, opaque ones keep their color
    assert torch.allclose(out.images[0, -1, 0], torch.ones(3), atol=1e-2)
    assert torch.allclose(out.images[0, 0, 0], torch.tensor([1.0, 0.0, 0.0]), atol=1e-2)
    assert out.masks[0, 0, 0, 0] == 1.0 and out.masks[0, -1, 0, 0] == 0.0


def test_camera_angle_x_and_black_background(tmp_path):
    root = write_scene(tmp_path / "s", camera_angle_x=2 * math.atan(0.5), split=False)
    out = parse(root, background=(0.0, 0.0, 0.0))
    assert torch.allclose(out.cameras.fx, torch.tensor([8.0, 8.0]))  # 0.5 * w / tan(angle / 2)
    assert torch.allclose(out.images[0, -1, 0], torch.zeros(3), atol=1e-2)
    assert TransformsDataParserConfig(data=root).setup().get_outputs("test") is None


def test_rgb_without_alpha_has_no_mask(tmp_path):
    out = parse(write_scene(tmp_path / "s", rgba=False))
    assert out.masks is None


def test_image_scale(tmp_path):
    out = parse(write_scene(tmp_path / "s", size=(8, 6)), image_scale=0.5)
    assert out.images.shape == (2, 3, 4, 3) and out.cameras.width == 4
    assert float(out.cameras.fx[0]) == 5.0


@pytest.mark.parametrize("breakage, message", [
    ("no_frames", "no frames"),
    ("missing_image", "image not found"),
    ("corrupt_image", "cannot decode"),
    ("sizes_differ", "differ in size"),
    ("bad_json", "not valid JSON"),
    ("nan_pose", "NaN"),
])
def test_bad_scenes_give_clear_errors(tmp_path, breakage, message):
    root = write_scene(tmp_path / "s")
    meta_path = root / "transforms_train.json"
    meta = json.loads(meta_path.read_text())
    if breakage == "no_frames":
        meta["frames"] = []
    elif breakage == "missing_image":
        (root / "r_1.png").unlink()
    elif breakage == "corrupt_image":
        (root / "r_1.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    elif breakage == "sizes_differ":
        write_image(root / "r_1.png", np.zeros((5, 5, 4), np.float32))
        for key in ("w", "h"):
            meta.pop(key)
    elif breakage == "nan_pose":
        meta["frames"][0]["transform_matrix"][0][3] = float("nan")
    if breakage == "bad_json":
        meta_path.write_text("{ not json")
    else:
        meta_path.write_text(json.dumps(meta))
    with pytest.raises(DataError, match=message):
        parse(root)


def test_missing_folder_and_format_detection(tmp_path):
    with pytest.raises(DataError, match="not found"):
        resolve_dataparser(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="cannot tell the format"):
        detect_format(tmp_path / "empty")
    assert detect_format(write_scene(tmp_path / "s")) == "transforms"


def test_datamanager_batches_carry_view_indices_and_foreground_share(tmp_path):
    root = write_scene(tmp_path / "s", n=3, size=(16, 16))
    # radius 4: the synthetic "object" (the top half of each image) must lie inside the bounding sphere
    config = DataManagerConfig(dataparser=TransformsDataParserConfig(data=root, scene_radius=4.0), rays_per_batch=400,
                               foreground_fraction=1.0)
    dm = DataManager(config)
    rays, batch = dm.next_train(0)
    assert rays.origins.shape == (400, 3) and batch["rgb"].shape == (400, 3)
    assert set(rays.camera_indices.tolist()) <= {0, 1, 2}
    assert (batch["mask"] > 0.5).all()  # every ray from the foreground
    # each ray starts at its own view's camera centre
    assert torch.allclose(rays.origins, dm.cameras.centers[rays.camera_indices])
    config.foreground_fraction = 0.0
    _, batch = DataManager(config).next_train(0)
    assert 0.3 < float((batch["mask"] > 0.5).float().mean()) < 0.7  # half the pixels are foreground


def test_datamanager_refuses_empty_masks(tmp_path):
    root = write_scene(tmp_path / "s")
    for i in range(2):
        write_image(root / f"r_{i}.png", np.zeros((6, 8, 4), np.float32))
    with pytest.raises(DataError, match="masks are empty"):
        DataManager(DataManagerConfig(dataparser=TransformsDataParserConfig(data=root)))


def test_border_foreground_counts_each_edge_pixel_once():
    from va_plugin.data.bounds import border_foreground
    masks = torch.zeros(2, 4, 5, 1)
    masks[0, 0, :, 0] = 1.0        # the whole top row: 5 of the 14 border pixels
    masks[1, 1:3, 1:4, 0] = 1.0    # inside only
    masks[1, 3, 4, 0] = 1.0        # one corner pixel
    assert border_foreground(masks) == pytest.approx([5 / 14, 1 / 14])


def test_an_object_cut_off_by_the_frame_is_warned_about(tiny_scene):
    from va_plugin.data.bounds import warn_object_cut_by_frame
    outputs = TransformsDataParserConfig(data=tiny_scene).setup().get_outputs("train")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the tiny scene keeps a margin: no warning
        assert max(warn_object_cut_by_frame(outputs)) == 0.0
    outputs.masks[1, -1, :, 0] = 1.0  # view 1's bottom row is now object
    with pytest.warns(UserWarning, match=r"cuts the object off in training view\(s\) \[1\]"):
        warn_object_cut_by_frame(outputs)


def test_gso_cream_is_the_dev_object_the_frame_cuts_off():
    """On the SyncDreamer rig, cream (a box) is cut off in all 4 input views; alarm is not."""
    from va_plugin.bench.scenes import gso
    from va_plugin.data.bounds import border_foreground
    root = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gso"
    if not (root / "alignment.json").is_file():
        pytest.skip(f"GSO data absent: {root}")
    for name, cut in (("cream", True), ("alarm", False)):
        alphas = torch.from_numpy(gso.load_renders(root, name, 256)[[0, 4, 8, 12], ..., 3:])
        shares = border_foreground(alphas)
        assert (min(shares) > 0.1) if cut else (max(shares) == 0.0), (name, shares)

