"""va-batch's parts without training: finding objects, the manifest, the reports, bad commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

from va_plugin.batch.inputs import find_objects
from va_plugin.batch.manifest import MANIFEST_FILE, Manifest
from va_plugin.batch.summary import contact_sheet, write_summary
from va_plugin.cli import batch as cli
from va_plugin.data.images import write_image
from va_plugin.errors import ConfigError


def test_objects_of_a_folder_and_of_a_list(tmp_path):
    root = tmp_path / "generated"
    for folder in ("syncdreamer", "zero123pp"):
        (root / folder).mkdir(parents=True)
        (root / folder / "cup.png").write_bytes(b"")  # detection happens in the job, not here
    (root / "syncdreamer" / "fox.png").write_bytes(b"")
    scene = root / "scenes" / "mug"
    (scene / "images").mkdir(parents=True)
    (scene / "transforms.json").write_text("{}")
    (scene / "images" / "0.png").write_bytes(b"")  # inside a scene folder: not an object of its own
    (root / ".hidden").mkdir()
    (root / ".hidden" / "x.png").write_bytes(b"")
    (root / "notes.txt").write_text("not an input")
    found = {o.name: o.path for o in find_objects(root)}
    assert found == {"mug": scene, "syncdreamer-cup": root / "syncdreamer" / "cup.png",
                     "fox": root / "syncdreamer" / "fox.png", "zero123pp-cup": root / "zero123pp" / "cup.png"}

    listing = tmp_path / "list.txt"
    listing.write_text(f"# objects\n\ngenerated/syncdreamer/fox.png\n{scene}\nmissing.png\n")
    listed = find_objects(listing)
    assert [o.name for o in listed] == ["fox", "mug", "missing"]
    assert listed[2].path == tmp_path / "missing.png"  # its job fails with "data not found"


@pytest.mark.parametrize("make, message", [
    (lambda p: p / "nope", "inputs not found"),
    (lambda p: p, "no inputs in"),
])
def test_inputs_without_objects_are_refused(tmp_path, make, message):
    with pytest.raises(ConfigError, match=message):
        find_objects(make(tmp_path))


def test_manifest_resumes_only_with_the_same_settings(tmp_path):
    settings = {"method": "neus", "options": {"steps": 3}}
    manifest = Manifest(tmp_path, settings, resume=False)
    manifest.add({"name": "a", "status": "ok", "cd": float("nan")})
    manifest.add({"name": "b", "status": "failed", "error": "bad"})
    with open(tmp_path / MANIFEST_FILE, "a") as handle:
        handle.write('{"name": "c", "sta')  # what a torn write would leave (the manifest is renamed into place)
    with pytest.raises(ConfigError, match="--resume"):
        Manifest(tmp_path, settings, resume=False)
    with pytest.raises(ConfigError, match=r"options\.steps: 3 -> 4"):
        Manifest(tmp_path, {"method": "neus", "options": {"steps": 4}}, resume=True)
    again = Manifest(tmp_path, settings, resume=True)
    assert set(again.records) == {"a", "b"} and again.records["a"]["cd"] is None
    assert again.finished("a") and again.finished("b") and not again.finished("c")
    assert not again.finished("b", retry_failed=True)
    assert not list(tmp_path.glob("*.tmp"))


def test_summary_and_contact_sheet(tmp_path):
    thumb = tmp_path / "thumb.png"
    write_image(thumb, np.full((8, 16, 3), 0.5, np.float32))
    records = [{"name": "a", "status": "ok", "seconds": 2.0, "cd": 0.1, "psnr": 20.0, "thumbnail": str(thumb)},
               {"name": "b", "status": "ok", "seconds": 4.0, "cd": 0.3, "thumbnail": str(thumb)},
               {"name": "c", "status": "failed", "seconds": 1.0, "error": "cannot | read"}]
    write_summary(tmp_path, records)
    lines = (tmp_path / "summary.csv").read_text().splitlines()
    assert lines[0].startswith("name,status,seconds,cd,iou,fscore,psnr,ssim,lpips")
    assert lines[1].startswith("a,ok,2,0.1,,,20,") and lines[3].startswith("c,failed,1,,")
    md = (tmp_path / "summary.md").read_text()
    assert "| **mean** (2 ok) |  | 3 | 0.2 |  |  | 20 |" in md and "cannot \\| read" in md
    sheet = contact_sheet(tmp_path, records, columns=2)
    from va_plugin.data.images import read_image

    assert read_image(sheet).shape[:2] == (2 * (8 + 16), 2 * 16)


@pytest.mark.parametrize("argv, message", [
    (["--method", "nope"], "unknown method"),
    (["--method", "neus", "--set", "pipeline.model.no_such_option=1"], "unknown option"),
    (["--method", "neus", "--preset", "turbo"], "unknown preset"),
    (["--method", "neus", "--workers", "0"], "at least 1"),
    (["--method", "neus", "--ray-address", "auto"], "need --engine ray"),
    (["--method", "neus", "--retry-failed"], "goes with --resume"),
    (["--method", "neus", "--texture-size", "100"], "power of two"),
])
def test_bad_commands_are_one_line(tmp_path, capsys, argv, message):
    code = cli.main([str(tmp_path), "--out", str(tmp_path / "out"), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not (tmp_path / "out").exists()


def test_missing_inputs_are_one_line(tmp_path, capsys):
    assert cli.main([str(tmp_path / "nothing"), "--method", "neus", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == f"error: inputs not found: {tmp_path / 'nothing'}"


def test_every_per_object_option_of_va_train_passes_through():
    names = cli.object_option_names()
    assert {"data_format", "views", "preset", "steps", "seed", "device", "overrides"} <= set(names)
    args = cli.build_parser().parse_args(["in", "--method", "neus", "--out", "o", "--views", "8", "--set", "a=1"])
    assert args.views == 8 and args.overrides == ["a=1"]
    json.dumps({name: getattr(args, name) for name in names})  # settings are stored as JSON
