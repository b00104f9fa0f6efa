"""The page's upload takes the new formats: an SV3D MP4, and a zip of a folder of four views read as one
4-view input; an undecodable video is one line."""

import zipfile

import numpy as np
import pytest
from conftest import toy_albedo, toy_object

from va_plugin.app.uploads import inspect_upload, stage_upload
from va_plugin.bench.scenes.layouts import write_layout
from va_plugin.data.rigfile import builtin_rigs, rig_cameras
from va_plugin.errors import DataError
from va_plugin.raycast import MeshRenderer, position_albedo

LIMIT = 50_000_000


def rendered(name, path, tile):
    spec = builtin_rigs()[name]
    renderer = MeshRenderer(toy_object(), position_albedo(toy_albedo))
    cameras = rig_cameras(spec, tile)
    return write_layout(path, spec, np.stack([renderer.render(cameras, k) for k in range(len(cameras))]))


def test_an_sv3d_video_upload_is_read_frame_by_frame(tmp_path):
    video = rendered("sv3d", tmp_path / "000000.mp4", 64)
    upload = stage_upload(video, tmp_path / "staging", LIMIT)
    inspection, _ = inspect_upload(upload, "neus")
    assert inspection.format == "sv3d" and inspection.views == 21 and len(inspection.gallery) == 21
    assert inspection.summary().startswith("SV3D video: 21 training views")


def test_a_zip_of_four_views_is_one_input(tmp_path):
    folder = rendered("four-view-folder", tmp_path / "views", 32)
    archive = tmp_path / "views.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for file in sorted(folder.iterdir()):
            zf.write(file, f"views/{file.name}")
    upload = stage_upload(archive, tmp_path / "staging", LIMIT)
    inspection, _ = inspect_upload(upload, "neus")
    assert inspection.format == "four-view-folder" and inspection.views == 4


def test_a_broken_video_is_one_line(tmp_path):
    broken = tmp_path / "clip.mp4"
    broken.write_bytes(b"\0" * 512)
    with pytest.raises(DataError, match="cannot decode video") as info:
        stage_upload(broken, tmp_path / "staging", LIMIT)
    assert len(str(info.value).splitlines()) == 1 and "staging" not in str(info.value)
