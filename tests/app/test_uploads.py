"""An uploaded scene reads only its own files: a ``transforms.json`` or ``scene.json`` entry that is
absolute, starts with ``~`` or leaves the upload with ``..`` is refused before any file it names is looked
at, with one message whatever the entry, so that an upload cannot read a server file nor learn whether one
exists (no page needed: :func:`stage_upload` is what the page calls)."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import pytest

from va_plugin.app.uploads import stage_upload
from va_plugin.errors import DataError

MAX_BYTES = 20_000_000


def _zip_scene(scene: Path, archive: Path, edit=None) -> Path:
    """``scene`` as ``archive`` (its files under ``scene/``), with ``edit(name, meta)`` applied to its jsons."""
    with zipfile.ZipFile(archive, "w") as bundle:
        for path in sorted(scene.rglob("*")):
            if not path.is_file():
                continue
            data = path.read_bytes()
            if path.suffix == ".json" and edit is not None:
                meta = json.loads(data)
                edit(path.name, meta)
                data = json.dumps(meta).encode()
            bundle.writestr(f"scene/{path.relative_to(scene).as_posix()}", data)
    return archive


@pytest.fixture
def server_files(tiny_scene, tmp_path):
    """A server's image (a copy of a view, so that it would decode) and a path where nothing is."""
    secret = tmp_path / "server" / "secret.png"
    secret.parent.mkdir()
    shutil.copyfile(next((tiny_scene / "images").glob("*.png")), secret)
    return secret, tmp_path / "server" / "missing.png"


def _entries(secret: Path, missing: Path, staging_depth: int = 6) -> list[str]:
    up = "../" * staging_depth
    return [str(secret), str(missing), str(secret.with_suffix("")), f"{up}{secret.relative_to('/')}",
            f"{up}{missing.relative_to('/')}", "images/../../../secret.png", "~/secret.png", "..\\..\\secret.png"]


def test_file_paths_outside_the_upload_are_refused_alike(tiny_scene, server_files, tmp_path):
    secret, missing = server_files
    staging = tmp_path / "staging"
    messages = set()
    for k, entry in enumerate(_entries(secret, missing)):
        def point_outside(name, meta, entry=entry):
            if name.startswith("transforms"):
                meta["frames"][0]["file_path"] = entry

        archive = _zip_scene(tiny_scene, tmp_path / f"up{k}.zip", point_outside)
        with pytest.raises(DataError) as refused:
            stage_upload(archive, staging, MAX_BYTES)
        message = str(refused.value).replace(archive.name, "UPLOAD")
        assert "outside the upload" in message and str(tmp_path) not in message and "secret" not in message
        messages.add(message)
        assert list(staging.iterdir()) == []  # nothing left behind
    # one message whatever the entry: an existing server file and a missing one are told apart by nothing
    assert len(messages) == 1, messages


def test_a_ground_truth_mesh_outside_the_upload_is_refused(tiny_scene, server_files, tmp_path):
    def mesh_outside(name, meta):
        if name == "scene.json":
            meta["mesh"] = str(server_files[0])

    with pytest.raises(DataError, match=r"scene\.json mesh names a file outside the upload"):
        stage_upload(_zip_scene(tiny_scene, tmp_path / "up.zip", mesh_outside), tmp_path / "staging", MAX_BYTES)


def test_a_scene_that_stays_inside_is_taken(tiny_scene, tmp_path):
    def harmless_dots(name, meta):
        if name.startswith("transforms"):
            first = meta["frames"][0]["file_path"]
            meta["frames"][0]["file_path"] = f"images/../{first}"

    upload = stage_upload(_zip_scene(tiny_scene, tmp_path / "up.zip", harmless_dots), tmp_path / "staging", MAX_BYTES)
    assert upload.path.is_dir() and upload.staging in upload.path.parents
