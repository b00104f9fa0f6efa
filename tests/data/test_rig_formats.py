"""Rig files and the generator formats they describe (Hunyuan3D-1, MV-Adapter, SV3D, Era3D, CRM, Wonder3D++,
4-view rigs): a small object rendered on each rig and written in each generator's layout must read back
with the rig's cameras and masks that match the render's alpha; the formats are detected from files of the
generators' real sizes and names; bad inputs and bad rig files give one line and exit 2."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import toy_albedo, toy_object

from va_plugin.api import build_config
from va_plugin.bench.scenes.layouts import assemble, write_layout, write_video
from va_plugin.cli import recon as recon_cli
from va_plugin.data import dataparsers, rigs
from va_plugin.data.dataparsers import DataFormat, detect_format, plugin_formats, resolve_dataparser
from va_plugin.data.dataparsers.rigged import (
    SyncDreamerDataParserConfig,
    Wonder3DDataParserConfig,
    Zero123ppDataParserConfig,
)
from va_plugin.data.images import write_image
from va_plugin.data.rigfile import (
    builtin_rigs,
    find_file,
    orbit_c2w,
    read_rig_file,
    rig_cameras,
    rig_from_dict,
    shown_name,
    view_files,
)
from va_plugin.errors import ConfigError, DataError
from va_plugin.raycast import MeshRenderer, position_albedo

TILE = 32
RIGS = sorted(builtin_rigs())
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
ZERO123PP_FOX = SHARED_DATA / "generated" / "zero123pp" / "fox.png"


@pytest.fixture(scope="module")
def renderer():
    return MeshRenderer(toy_object(), position_albedo(toy_albedo))


def renders(renderer, cameras) -> np.ndarray:
    """RGBA renders ``[n, t, t, 4]`` of the toy object."""
    return np.stack([renderer.render(cameras, k) for k in range(len(cameras))])


def parse(path, data_format="auto", **options):
    config = resolve_dataparser(Path(path), data_format)
    for key, value in options.items():
        setattr(config, key, value)
    return config.setup().get_outputs("train")


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def written(renderer, tmp_path, name, tile=TILE, **kwargs):
    spec = builtin_rigs()[name]
    rgba = renders(renderer, rig_cameras(spec, tile))
    suffix = {"grid": ".png", "strip": ".png", "video": ".mp4"}.get(spec.layout, "")
    return write_layout(tmp_path / f"{name}{suffix}", spec, rgba, **kwargs), rgba


# -- the rig cameras --------------------------------------------------------------------------------
def test_orbit_cameras_match_the_z_up_rigs_and_define_top_and_bottom_views():
    azimuths, elevations = [0.0, 90.0, 200.0], [0.0, 30.0, -20.0]
    expected = rigs.look_at_origin(rigs.orbit_eyes(azimuths, elevations, 1.5))
    assert torch.allclose(orbit_c2w(azimuths, elevations, 1.5), expected, atol=1e-5)
    # CRM's top view (imagedream/camera_utils.py, y up there): image right is the front camera's right (+y
    # here), image up points away from the front view (-x here); the bottom view's image up points to it
    top, bottom = orbit_c2w([0.0, 0.0], [90.0, -90.0], 2.0)
    assert torch.allclose(top[:, 0], torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)  # x right
    assert torch.allclose(top[:, 1], torch.tensor([1.0, 0.0, 0.0]), atol=1e-6)  # y down = +x
    assert torch.allclose(top[:, 2], torch.tensor([0.0, 0.0, -1.0]), atol=1e-6)  # looking down
    assert torch.allclose(bottom[:, 1], torch.tensor([-1.0, 0.0, 0.0]), atol=1e-6)


def test_builtin_rigs_hold_the_values_of_the_generators_code():
    rig = builtin_rigs()
    # Hunyuan3D-1 std: tiles row by row; its code takes them in the order 0, 2, 4, 5, 3, 1 for azimuth 0..300
    std = rig["hunyuan3d-std"]
    assert [std.azimuths[t] for t in (0, 2, 4, 5, 3, 1)] == [0, 60, 120, 180, 240, 300]
    assert (std.rows, std.columns, std.tile_sizes, std.distance) == (3, 2, (512,), 1.5)
    assert abs(std.fov_deg - 2 * np.degrees(np.arctan(16 / 35))) < 0.01  # normalised focal 35/32
    sv3d = rig["sv3d"]
    assert sv3d.count == 21 and sv3d.azimuths[-1] % 360 == pytest.approx(0.0, abs=1e-6)  # the last frame: input
    assert sv3d.azimuths[0] == pytest.approx(360 / 21) and set(sv3d.elevations) == {10.0}
    crm = rig["crm"]
    assert crm.view_names == ("left", "bottom", "back", "right", "top", "front")
    assert crm.elevations == (0, -90, 0, 0, 90, 0) and crm.azimuths[0] == 270 and crm.background == (0.5,) * 3
    mva = rig["mvadapter"]
    assert mva.azimuths == (0, 45, 90, 180, 270, 315) and mva.ortho_scale == pytest.approx(1.1)
    assert rig["era3d"].files == ("color_{view}_masked.png",) and rig["era3d"].normals == "normals_{view}_masked.png"
    assert all(spec.source for spec in rig.values())  # every built-in rig cites where its values come from


def test_the_first_generators_rig_files_give_their_rigs_bit_for_bit():
    """SyncDreamer, Zero123++ and Wonder3D read through rig files must keep the cameras their own parsers
    gave (:mod:`va_plugin.data.rigs`), to the bit: runs on their inputs must not change."""
    def same(a, b):
        return all(torch.equal(getattr(a, k), getattr(b, k)) for k in ("c2w", "fx", "fy", "cx", "cy")) and \
            (a.camera_type, a.pixel_offset, a.width) == (b.camera_type, b.pixel_offset, b.width)

    for tile in (32, 256, 300):
        for elevation, offset in ((30.0, 0.5), (12.25, 0.0), (-45.5, 0.5)):
            spec = SyncDreamerDataParserConfig(elevation_deg=elevation, pixel_offset=offset).spec()
            assert same(rig_cameras(spec, tile), rigs.syncdreamer_rig(tile, elevation, offset))
        for version in ("v1.1", "v1.2"):
            spec = Zero123ppDataParserConfig(rig=version).spec()
            assert same(rig_cameras(spec, tile), rigs.zero123pp_rig(version, tile))
        spec = Wonder3DDataParserConfig(ortho_scale=1.2).spec()
        assert same(rig_cameras(spec, tile), rigs.wonder3d_rig(tile, 1.2))
    assert float(rig_cameras(builtin_rigs()["syncdreamer"], 256).fx[0]) == 280.0


def test_folder_patterns_match_index_and_any_extension_and_prefer_the_first_complete(tmp_path):
    spec = rig_from_dict({"layout": {"type": "folder", "files": ["sub/rgb_{index}_{view}", "rgb_{index}_{view}"]},
                          "views": {"names": ["right", "front_right"], "azimuths": [90, 45], "elevation": 0},
                          "camera": {"type": "orthographic", "scale": 1}})
    for name in ("rgb_000_front_right.png", "rgb_right.JPG", "rgb_x_right.png", "notes_right.txt"):
        (tmp_path / name).write_bytes(b"")
    assert find_file(tmp_path, "rgb_{index}_{view}", "right").name == "rgb_right.JPG"
    assert find_file(tmp_path, "rgb_{index}_{view}", "front_right").name == "rgb_000_front_right.png"
    assert find_file(tmp_path, "rgb_{index}_{view}.png", "right") is None
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "rgb_001_right.png").write_bytes(b"")
    assert view_files(spec, tmp_path)[0] == "rgb_{index}_{view}"  # sub/ lacks front_right
    (tmp_path / "sub" / "rgb_001_front_right.webp").write_bytes(b"")
    pattern, files = view_files(spec, tmp_path)
    assert pattern.startswith("sub/") and [f.name for f in files] == ["rgb_001_right.png", "rgb_001_front_right.webp"]
    assert shown_name("sub/rgb_{index}_{view}", "back") == "sub/rgb_000_back.png"


# -- each reader on data it did not write -----------------------------------------------------------
@pytest.mark.parametrize("name", RIGS)
def test_each_generator_layout_reads_back_with_its_rig(name, renderer, tmp_path, recwarn):
    tile = 64 if name == "sv3d" else TILE  # mp4v needs a few macroblocks to keep the edges
    path, rgba = written(renderer, tmp_path, name, tile)
    train = parse(path, name)
    spec = builtin_rigs()[name]
    assert len(train) == spec.count and train.images.shape[1:3] == (tile, tile)
    assert train.metadata["format"] == name
    assert train.cameras.camera_type == spec.camera_type
    ious = [iou(m[..., 0].numpy() > 0.5, a[..., 3] > 0.01) for m, a in zip(train.masks, rgba)]
    assert min(ious) > 0.85, ious
    assert np.mean(train.metadata["silhouette_iou"]) > 0.8
    assert not [w for w in recwarn if "agree poorly" in str(w.message)]
    if spec.normals:
        assert "normals" not in train.metadata  # written without normal maps


def test_hunyuan_std_grid_assembled_as_its_code_does(renderer, tmp_path):
    """Renders at azimuth 0, 60, ..., 300 placed in the grid so that its code's order 0, 2, 4, 5, 3, 1 reads
    them back in azimuth order: each tile gets the camera at its render's azimuth."""
    by_azimuth = rigs.look_at_origin(rigs.orbit_eyes([60.0 * k for k in range(6)], 0.0, 1.5))
    spec = builtin_rigs()["hunyuan3d-std"]
    cameras = rig_cameras(spec, TILE)
    rgba = renders(renderer, type(cameras)(by_azimuth, cameras.fx, cameras.fy, cameras.cx, cameras.cy,
                                            TILE, TILE, pixel_offset=0.5))
    tiles = [None] * 6
    for k, tile in enumerate((0, 2, 4, 5, 3, 1)):
        tiles[tile] = rgba[k, ..., :3] * rgba[k, ..., 3:] + (1 - rgba[k, ..., 3:])
    path = tmp_path / "sample_views.jpg"
    write_image(path, np.concatenate([np.concatenate(tiles[2 * r:2 * r + 2], 1) for r in range(3)], 0))
    train = parse(path, "hunyuan3d-std")
    assert np.mean(train.metadata["silhouette_iou"]) > 0.8
    for k, tile in enumerate((0, 2, 4, 5, 3, 1)):
        # the viewing direction survives the normalisation (a shift and a scale)
        assert torch.allclose(train.cameras.c2w[tile, :, 2], by_azimuth[k, :, 2], atol=1e-4), (k, tile)


def test_crm_strip_in_its_view_order(renderer, tmp_path):
    """left, bottom, back, right, top, front as CRM's camera_views [1, 2, 3, 4, 5, 0] say (grey background)."""
    angles = {"left": (270, 0), "bottom": (0, -90), "back": (180, 0), "right": (90, 0), "top": (0, 90),
              "front": (0, 0)}
    order = ["left", "bottom", "back", "right", "top", "front"]
    c2w = orbit_c2w([angles[v][0] for v in order], [angles[v][1] for v in order], 2.0)
    cameras = rig_cameras(builtin_rigs()["crm"], TILE)
    rgba = renders(renderer, type(cameras)(c2w, cameras.fx, cameras.fy, cameras.cx, cameras.cy, TILE, TILE,
                                           camera_type=cameras.camera_type, pixel_offset=0.5))
    path = tmp_path / "pixel_images.png"
    write_image(path, np.concatenate(list(rgba[..., :3] * rgba[..., 3:] + 0.5 * (1 - rgba[..., 3:])), 1))
    train = parse(path, "crm")
    assert np.mean(train.metadata["silhouette_iou"]) > 0.8


def test_era3d_normals_are_read_in_the_front_frame(renderer, tmp_path):
    spec = builtin_rigs()["era3d"]
    cameras = rig_cameras(spec, TILE)
    rgba = renders(renderer, cameras)
    front_gl = cameras.c2w[0, :, :3].numpy() * np.array([1.0, -1.0, -1.0])
    maps = []
    for k in range(len(cameras)):
        origins, directions = renderer.pixel_rays(cameras, k)
        t, faces, bary = renderer.cast(origins, directions)
        hit = np.isfinite(t)
        world = np.zeros((TILE * TILE, 3), np.float32)
        world[hit] = np.einsum("nk,nkc->nc", bary[hit], renderer.vertex_normals[renderer.faces[faces[hit]]])
        maps.append(np.concatenate([(world @ front_gl + 1) / 2, hit[:, None]], -1).reshape(TILE, TILE, 4))
    path = write_layout(tmp_path / "scene", spec, rgba, normals=np.stack(maps).astype(np.float32))
    train = parse(path, "era3d")
    normals = train.metadata["normals"]
    assert normals.shape == (6, TILE, TILE, 3)
    # the right view (azimuth 90) sees mostly normals towards +y
    seen = normals[2][normals[2].norm(dim=-1) > 0.5]
    assert seen[:, 1].mean() > 0.5


def test_a_user_rig_file_reads_like_the_builtin_one(renderer, tmp_path):
    path, _ = written(renderer, tmp_path, "four-view-grid")
    rig = tmp_path / "mine.json"
    rig.write_text(json.dumps({"name": "mine", "layout": {"type": "grid", "rows": 2, "columns": 2},
                               "views": {"azimuths": [0, 90, 180, 270], "elevation": 15},
                               "camera": {"type": "perspective", "fov_deg": 40, "distance": 2},
                               "background": "white"}))
    ours = parse(path, "four-view-grid")
    config = build_config("neus", path, rig=rig)
    theirs = config.pipeline.datamanager.dataparser.setup().get_outputs("train")
    assert torch.allclose(ours.cameras.c2w, theirs.cameras.c2w) and theirs.metadata["format"] == "mine"
    yaml_rig = tmp_path / "mine.yaml"
    yaml_rig.write_text("layout: {type: grid, rows: 2, columns: 2}\nviews: {azimuths: [0, 90, 180, 270], "
                        "elevation: 15}\ncamera: {type: perspective, fov_deg: 40}\n")
    assert read_rig_file(yaml_rig).name == "mine"


def test_elevation_and_fov_options(renderer, tmp_path):
    path, _ = written(renderer, tmp_path, "four-view-grid")
    parser = build_config("neus", path, data_format="four-view-grid", elevation=5.0, fov=30.0) \
        .pipeline.datamanager.dataparser
    spec = parser.spec()
    assert set(spec.elevations) == {5.0} and spec.fov_deg == 30.0
    with pytest.raises(DataError, match="orthographic; --fov applies to perspective rigs only"):
        build_config("neus", path, data_format="mvadapter", fov=30.0)
    with pytest.raises(DataError, match="gives each view its own elevation"):
        build_config("neus", path, data_format="crm", elevation=5.0)
    with pytest.raises(ConfigError, match=r"--fov applies to rig-format \(perspective\) inputs only"):
        build_config("neus", path, data_format="zero123pp", fov=30.0)


# -- detection ----------------------------------------------------------------------------------------
def blank(path: Path, height: int, width: int) -> Path:
    write_image(path, np.ones((height, width, 3), np.float32))
    return path


def test_formats_are_detected_from_their_real_sizes_and_names(tmp_path, renderer):
    assert detect_format(blank(tmp_path / "a.png", 1536, 1024)) == "hunyuan3d-std"
    assert detect_format(blank(tmp_path / "out_views.jpg", 960, 640)) == "hunyuan3d-lite"
    assert detect_format(blank(tmp_path / "grid.png", 960, 640)) == "zero123pp"  # Zero123++'s size, not named
    assert detect_format(blank(tmp_path / "pixel_images.png", 256, 1536)) == "crm"
    assert detect_format(blank(tmp_path / "output.png", 768, 6 * 768)) == "mvadapter"
    assert detect_format(blank(tmp_path / "sd21.png", 512, 6 * 512)) == "mvadapter"
    with pytest.raises(DataError, match="cannot tell the format"):  # a square image: one view, or 2 x 2?
        detect_format(blank(tmp_path / "grid4.png", 512, 512))
    assert detect_format(blank(tmp_path / "row4.png", 256, 1024)) == "four-view-row"
    video = write_video(tmp_path / "000000.mp4", np.ones((3, 16, 16, 3), np.float32))
    assert detect_format(video) == "sv3d"
    era3d, _ = written(renderer, tmp_path, "era3d")
    assert detect_format(era3d) == "era3d"
    frames = tmp_path / "frames"
    for k in range(21):
        blank(frames / f"{k:03d}.png", 16, 16)
    assert detect_format(frames) == "sv3d"
    four = tmp_path / "four"
    for k in range(4):
        blank(four / f"{k}.png", 16, 16)
    assert detect_format(four) == "four-view-folder"


def test_a_tie_names_the_candidates_in_one_line(tmp_path, monkeypatch):
    crm = builtin_rigs()["crm"]
    monkeypatch.setitem(dataparsers.FORMATS, "crm-copy", dataparsers._rig_format(crm, "crm"))
    with pytest.raises(DataError) as info:
        detect_format(blank(tmp_path / "pixel_images.png", 256, 1536))
    assert str(info.value).endswith("could be any of crm, crm-copy; choose one with --data-format")
    assert len(str(info.value).splitlines()) == 1


def test_formats_register_through_an_entry_point(monkeypatch, tmp_path):
    class EntryPoint:
        name = "my-gen"

        def load(self):
            return {"layout": {"type": "strip", "count": 3, "tile_sizes": [100]}, "views": {
                "azimuths": [0, 120, 240], "elevation": 5}, "camera": {"type": "orthographic", "scale": 1.2}}

    monkeypatch.setattr(dataparsers.metadata, "entry_points", lambda group: [EntryPoint()])
    found = plugin_formats()
    assert isinstance(found["my-gen"], DataFormat)
    assert found["my-gen"].detect(blank(tmp_path / "x.png", 100, 300)) == 2
    config = found["my-gen"].make_config()
    assert config.spec().count == 3 and config.spec().name == "my-gen"


# -- a wrong rig is not meshed silently --------------------------------------------------------------
def test_six_views_of_another_rig_read_as_hunyuan3d_warn(renderer, tmp_path):
    """MV-Adapter's six views (azimuth 0, 45, 90, 180, 270, 315, orthographic) in Hunyuan3D's grid: the worst
    view's silhouette is not explained by the others under Hunyuan3D's rig."""
    spec = builtin_rigs()["mvadapter"]
    rgba = renders(renderer, rig_cameras(spec, 64))
    views = rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:])
    path = tmp_path / "six.png"
    write_image(path, assemble(views, builtin_rigs()["hunyuan3d-std"]))
    with pytest.warns(UserWarning, match="masks agree poorly with the hunyuan3d-std rig"):
        parse(path, "hunyuan3d-std")


# -- bad input: one line, exit 2 ------------------------------------------------------------------
def run_recon(argv, tmp_path, capsys):
    code = recon_cli.main([*argv, "--out", str(tmp_path / "run"), "--steps", "1", "--quiet"])
    err = capsys.readouterr().err.strip()
    return code, err


def test_missing_view_file_is_one_line(renderer, tmp_path, capsys):
    folder, _ = written(renderer, tmp_path, "era3d")
    (folder / "color_back_masked.png").unlink()
    code, err = run_recon([str(folder)], tmp_path, capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "missing the era3d view file(s) color_back_masked.png" in err
    assert not (tmp_path / "run").exists()


def test_video_with_the_wrong_frame_count_is_one_line(tmp_path, capsys):
    video = write_video(tmp_path / "000000.mp4", np.ones((20, 16, 16, 3), np.float32))
    code, err = run_recon([str(video)], tmp_path, capsys)
    assert code == 2 and err == f"error: {video} holds 20 frames; sv3d writes 21"


def test_grid_of_the_wrong_size_is_one_line(tmp_path, capsys):
    image = blank(tmp_path / "odd.png", 100, 70)
    code, err = run_recon([str(image), "--data-format", "hunyuan3d-std"], tmp_path, capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "odd.png is 70 wide x 100 high; expected hunyuan3d-std: one image of 3 rows x 2 columns" in err


@pytest.mark.parametrize("rig, message", [
    ({"views": {"azimuths": [0], "elevation": 0}, "camera": {"type": "perspective", "fov_deg": 40}},
     "is missing the field 'layout'"),
    ({"layout": {"type": "strip", "count": 4}, "views": {"elevation": 0},
      "camera": {"type": "perspective", "fov_deg": 40}}, "views is missing the field 'azimuths'"),
    ({"layout": {"type": "strip", "count": 4}, "views": {"azimuths": [0, 90, 180], "elevation": 0},
      "camera": {"type": "perspective", "fov_deg": 40}}, "lists 3 azimuths but the layout holds 4 views"),
    ({"layout": {"type": "strip", "count": 2}, "views": {"azimuths": [0, 90], "elevation": 0},
      "camera": {"type": "perspective", "fov_deg": 40, "scale": 1.0}}, "is perspective but gives an orthographic"),
    ({"layout": {"type": "grid", "rows": 2, "columns": 2, "count": 6}, "views": {"azimuths": [0, 90, 180, 270],
      "elevation": 0}, "camera": {"type": "orthographic", "scale": 1}}, "but rows x columns is 4"),
    ({"layout": {"type": "strip", "count": 2}, "views": {"azimuths": [0, 90], "elevation": 0, "elevations": [0, 0]},
      "camera": {"type": "orthographic", "scale": 1}}, "has both 'elevation' and 'elevations'"),
    ({"layout": {"type": "strip", "count": 2}, "views": {"azimuths": [0, 90], "elevation": 0},
      "camera": {"type": "perspective", "fov_deg": 190}}, "the field of view must be a number between 0 and 170"),
    ({"layout": {"type": "strip", "count": 2}, "views": {"azimuths": [0, 90], "elevation": 0},
      "camera": {"type": "perspective", "fov_deg": 40, "focal": 1.2}}, "gives both 'fov_deg' and 'focal'"),
    ({"layout": {"type": "strip", "count": 2}, "views": {"azimuths": [0, 90], "elevation": 0},
      "camera": {"type": "perspective", "focal": 1.2, "pixel_offset": 2}}, "pixel_offset must be from 0 to 1"),
    ({"layout": {"type": "strip", "count": 2, "any_size": True}, "views": {"azimuths": [0, 90], "elevation": 0},
      "camera": {"type": "orthographic", "scale": 1}}, "true needs layout.tile_sizes"),
])
def test_bad_rig_files_are_one_line(rig, message, renderer, tmp_path, capsys):
    with pytest.raises(DataError, match=message.replace("(", r"\(")):
        rig_from_dict(rig, where="rig")
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(rig))
    image = blank(tmp_path / "in.png", 16, 32)
    code, err = run_recon([str(image), "--rig", str(path)], tmp_path, capsys)
    assert code == 2 and len(err.splitlines()) == 1 and err.startswith(f"error: rig file {path}")
    assert message in err


def test_a_missing_or_broken_rig_file_is_one_line(tmp_path, capsys):
    image = blank(tmp_path / "in.png", 16, 32)
    code, err = run_recon([str(image), "--rig", str(tmp_path / "none.json")], tmp_path, capsys)
    assert code == 2 and err == f"error: rig file not found: {tmp_path / 'none.json'}"
    broken = tmp_path / "broken.json"
    broken.write_text("{\"layout\": ")
    code, err = run_recon([str(image), "--rig", str(broken)], tmp_path, capsys)
    assert code == 2 and "is not valid JSON" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("extra, message", [
    (["--data-format", "crm", "--elevation", "5"], "rig crm gives each view its own elevation"),
    (["--data-format", "mvadapter", "--fov", "30"], "rig mvadapter is orthographic; --fov applies"),
    (["--data-format", "zero123pp", "--rig", "sv3d"], "--rig sv3d and --data-format zero123pp disagree"),
])
def test_recon_rig_options_that_do_not_apply_are_one_line(extra, message, tmp_path, capsys):
    image = blank(tmp_path / "pixel_images.png", 16, 96)
    code, err = run_recon([str(image), *extra], tmp_path, capsys)
    assert code == 2 and len(err.splitlines()) == 1 and message in err



@pytest.mark.skipif(not ZERO123PP_FOX.is_file(), reason=f"generator outputs absent: {ZERO123PP_FOX}")
def test_a_real_zero123pp_grid_read_through_a_users_rig_file_fits_like_its_own_parser(tmp_path):
    """Zero123++ v1.2 described as a user would (alternating elevations, FOV 30): the same cameras and the
    same silhouette fit as the built-in zero123pp parser, through the rig-file path."""
    rig = tmp_path / "zero123pp.json"
    rig.write_text(json.dumps({
        "name": "zero123pp-by-hand", "layout": {"type": "grid", "rows": 3, "columns": 2},
        "views": {"azimuths": [30, 90, 150, 210, 270, 330], "elevations": [20, -10, 20, -10, 20, -10]},
        "camera": {"type": "perspective", "fov_deg": 30, "distance": 2.0}, "background": "grey"}))
    ours = parse(ZERO123PP_FOX, "zero123pp")
    theirs = build_config("neus", ZERO123PP_FOX, rig=rig).pipeline.datamanager.dataparser.setup().get_outputs("train")
    assert torch.allclose(ours.cameras.c2w, theirs.cameras.c2w, atol=1e-5)
    assert theirs.metadata["silhouette_iou"] == ours.metadata["silhouette_iou"]
