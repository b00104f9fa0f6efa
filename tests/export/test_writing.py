"""Files of a baked texture: GLB and OBJ+MTL+PNG that load back with their texture."""

import numpy as np
import pytest
import trimesh
from texture_cases import SIX_SIDES, TEXTURE, cube, cube_views

from va_plugin.errors import VAError
from va_plugin.export.texture import bake_texture
from va_plugin.export.writing import check_texture_output, write_textured_mesh


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_written_files_load_back_with_their_texture(tmp_path, suffix):
    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, _ = bake_texture(mesh, views, size=TEXTURE)
    written = write_textured_mesh(textured, tmp_path / f"cube{suffix}")
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(p.name for p in written)
    if suffix == ".obj":
        assert names == ["cube.mtl", "cube.obj", "cube.png", "cube_frame.json"]
        assert "cube.png" in (tmp_path / "cube.mtl").read_text()
    loaded = trimesh.load(tmp_path / f"cube{suffix}", force="mesh")
    image = np.asarray(loaded.visual.material.to_simple().image if suffix == ".glb"
                       else loaded.visual.material.image).astype(np.float32)[..., :3] / 255
    assert image.shape == (TEXTURE, TEXTURE, 3)
    assert np.abs(image - textured.image).max() < 1.5 / 255
    assert len(loaded.faces) == len(textured.faces)
    # UVs survive the round trip (GLB stores v down; trimesh flips it back)
    assert np.abs(np.sort(loaded.visual.uv, 0) - np.sort(textured.uv, 0)).max() < 1e-4


def test_other_formats_are_refused(tmp_path):
    with pytest.raises(VAError, match=r"\.glb or \.obj"):
        check_texture_output(tmp_path / "mesh.ply")


def test_glb_and_obj_written_at_once_share_their_frame_record_safely(tmp_path):
    """The bake writes its GLB and OBJ in two threads; both write ``<stem>_frame.json``. Each write has
    temporary files of its own, so neither renames away the other's (a shared temporary name failed with
    FileNotFoundError now and then)."""
    from concurrent.futures import ThreadPoolExecutor

    mesh = cube()
    views = cube_views(mesh, SIX_SIDES["azimuths"], SIX_SIDES["elevations"])
    textured, _ = bake_texture(mesh, views, size=TEXTURE)
    textured.image = np.ascontiguousarray(np.tile(textured.image, (8, 8, 1)))  # a longer encode: a wider window
    outs = [tmp_path / "mesh.glb", tmp_path / "mesh.obj"]
    with ThreadPoolExecutor(max_workers=2) as pool:
        for _ in range(30):
            list(pool.map(lambda path: write_textured_mesh(textured, path), outs))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mesh.glb", "mesh.mtl", "mesh.obj", "mesh.png",
                                                          "mesh_frame.json"]
