"""va-batch takes every generator format: videos are objects, an Era3D folder is one object, and a folder of
four outputs stays four objects (not one 4-view folder)."""

import numpy as np

from va_plugin.batch.inputs import find_objects
from va_plugin.bench.scenes.layouts import write_video
from va_plugin.data.images import write_image


def test_videos_and_generator_folders_are_objects(tmp_path):
    write_video(tmp_path / "sv3d" / "000000.mp4", np.ones((21, 16, 16, 3), np.float32))
    era3d = tmp_path / "era3d" / "chair"
    for view in ("front", "front_right", "right", "back", "left", "front_left"):
        write_image(era3d / f"color_{view}_masked.png", np.ones((16, 16, 3), np.float32))
        write_image(era3d / f"normals_{view}_masked.png", np.ones((16, 16, 3), np.float32))
    for k in range(4):
        write_image(tmp_path / "strips" / f"s{k}.png", np.ones((16, 256, 3), np.float32))
    found = {o.name: o.path for o in find_objects(tmp_path)}
    assert found["000000"] == tmp_path / "sv3d" / "000000.mp4"
    assert found["chair"] == era3d  # one object, its 12 images not searched
    assert {"s0", "s1", "s2", "s3"} <= set(found) and len(found) == 6
    assert [o.path for o in find_objects(tmp_path / "sv3d" / "000000.mp4")] == [tmp_path / "sv3d" / "000000.mp4"]
