"""What the page does with an upload before any training: take it in, and show what it holds.

:func:`stage_upload` copies an image, or safely unpacks a zip, into a staging folder of its own (never a
run folder) and finds the one object in it; :func:`inspect_upload` reads it the way training will (the
format, the training views, their masks) and returns the pictures for the page. Anything unusable raises
:class:`~va_plugin.errors.VAError` with one line that names the upload, not the staging folder.
"""

from __future__ import annotations

import os
import shutil
import uuid
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PureWindowsPath

import numpy as np

from va_plugin.api import QUALITIES, build_config
from va_plugin.batch.inputs import find_objects
from va_plugin.data.dataparsers import FORMATS, detect_format, image_shape
from va_plugin.data.dataparsers.generators import IMAGE_SUFFIXES, image_files
from va_plugin.data.dataparsers.transforms import referenced_files
from va_plugin.data.foreground import mask_picture
from va_plugin.data.images import VIDEO_SUFFIXES, read_video
from va_plugin.engine.options import check_views
from va_plugin.errors import ConfigError, DataError, VAError

FORMAT_NAMES = {"syncdreamer": "SyncDreamer strip", "zero123pp": "Zero123++ grid", "wonder3d": "Wonder3D folder",
                "transforms": "transforms.json scene", "hunyuan3d-std": "Hunyuan3D-1 grid",
                "hunyuan3d-lite": "Hunyuan3D-1 lite grid", "mvadapter": "MV-Adapter row", "sv3d": "SV3D video",
                "era3d": "Era3D folder", "crm": "CRM strip", "four-view-grid": "4-view grid",
                "four-view-row": "4-view row", "four-view-folder": "4-view folder"}
VIEW_CHOICES = ("all", "4", "8", "12", "16")
"""The page's choices of training views (SyncDreamer strips)."""
ZIP_RATIO = 10
"""A zip may unpack to at most this many times the upload limit."""
MAX_ZIP_FILES = 5000
ACCEPTED = ("an image (a SyncDreamer strip, a Zero123++, Hunyuan3D-1 or 4-view grid, an MV-Adapter row, a CRM "
            "strip), an SV3D MP4, or a zip of a Wonder3D, Era3D, 4-view or transforms.json folder")


@dataclass
class Upload:
    """An upload taken in: the user's file name, the input to train on, and the staging folder holding it."""

    name: str
    path: Path
    staging: Path

    def tell(self, message: str) -> str:
        """``message`` with the staging folder's paths shown as paths in the upload."""
        return message.replace(f"{self.staging}/", "").replace(str(self.staging), self.name)

    def discard(self) -> None:
        shutil.rmtree(self.staging, ignore_errors=True)


@dataclass
class Inspection:
    """What training will see of an upload."""

    format: str
    views: int
    """Training views."""
    total_views: int
    """Views in the input (training and held out)."""
    masks: str
    """Where the masks come from."""
    view_size: tuple[int, int]
    """Width and height of a view."""
    gallery: list[tuple[np.ndarray, str]]
    """Each training view above its mask (uint8 RGB), with a caption."""
    notes: list[str] = field(default_factory=list)
    """Warnings of the data checks, and options that do not apply."""

    def summary(self) -> str:
        line = (f"{FORMAT_NAMES.get(self.format, self.format)}: {self.views} training views"
                f"{f' of {self.total_views}' if self.total_views != self.views else ''}, "
                f"{self.view_size[0]} x {self.view_size[1]} px, masks from the {self.masks}")
        return "\n".join([line, *(f"note: {n}" for n in self.notes)])


def _megabytes(size: float) -> str:
    return f"{size / 1e6:.0f} MB" if size >= 1e7 else f"{size / 1e6:.2f} MB"


def _unpack(archive: Path, into: Path, max_bytes: int, name: str) -> None:
    """Unpack a zip into ``into``, refusing paths that leave it, links, and archives too large unpacked."""
    try:
        with zipfile.ZipFile(archive) as handle:
            members = [m for m in handle.infolist() if not m.is_dir()]
            if len(members) > MAX_ZIP_FILES:
                raise DataError(f"{name} holds {len(members)} files; the app takes at most {MAX_ZIP_FILES}")
            total = sum(m.file_size for m in members)
            if total > max_bytes * ZIP_RATIO:
                raise DataError(f"{name} unpacks to {_megabytes(total)}; the app takes at most "
                                f"{_megabytes(max_bytes * ZIP_RATIO)} unpacked")
            root = into.resolve()
            for member in members:
                parts = Path(member.filename.replace("\\", "/")).parts
                if member.filename.startswith(("/", "\\")) or ".." in parts or (parts and ":" in parts[0]):
                    raise DataError(f"{name} holds a path outside the archive ({member.filename}); refused")
                if (member.external_attr >> 16) & 0o170000 == 0o120000:
                    raise DataError(f"{name} holds a symbolic link ({member.filename}); refused")
                if parts[0] == "__MACOSX" or any(p.startswith(".") for p in parts):
                    continue
                target = (root / Path(*parts)).resolve()
                target.parent.mkdir(parents=True, exist_ok=True)
                with handle.open(member) as source, open(target, "wb") as sink:
                    shutil.copyfileobj(source, sink)
    except zipfile.BadZipFile:
        raise DataError(f"{name} is not a readable zip archive (corrupt or truncated)") from None
    except (zlib.error, EOFError, NotImplementedError, RuntimeError, OSError) as exc:
        detail = str(exc).strip().splitlines()[0][:80] if str(exc).strip() else type(exc).__name__
        raise DataError(f"cannot unpack {name}: {detail}") from None


def _one_input(folder: Path) -> bool:
    """A folder of image files only that some format reads as one input."""
    files = [p for p in folder.iterdir() if not p.name.startswith(".")]
    if not files or len(image_files(folder)) != len(files):
        return False
    return any(fmt.detect(folder) for fmt in FORMATS.values())


def check_confined(folder: Path, name: str) -> None:
    """Refuse an unpacked upload whose scene files name a file outside it (an absolute path, a ``~`` or
    ``..`` that leaves it): the app reads only the upload's own files. Decided on the text of each entry
    before any file it names is looked at, with one message whatever the entry, so that an upload learns
    nothing of the server's files."""
    root = os.path.normpath(os.path.abspath(folder))
    for json_path, where, entry in referenced_files(folder):
        text = entry.replace("\\", "/")
        joined = os.path.normpath(os.path.join(os.fspath(json_path.parent), text))
        leaves = (text.startswith(("/", "~")) or PureWindowsPath(entry).drive != ""
                  or os.path.commonpath([root, joined]) != root)
        if not leaves:
            target = Path(joined).with_suffix(".png") if not Path(joined).suffix else Path(joined)
            leaves = not Path(os.path.realpath(target)).is_relative_to(os.path.realpath(root))
        if leaves:
            raise DataError(f"{name}: {json_path.relative_to(folder).as_posix()} {where} names a file outside the "
                            "upload; the app reads only the files inside an upload (use paths relative to the "
                            "json, without ..)")


def _object_in(folder: Path, name: str) -> Path:
    """The one generator output or scene folder below ``folder`` (an unpacked zip)."""
    try:
        found = find_objects(folder)
    except ConfigError:
        found = []
    if len(found) != 1:  # a folder of 4 views or 21 frames is one input here, not four or 21
        whole = [f for f in (folder, *(p for p in folder.iterdir() if p.is_dir())) if _one_input(f)]
        if len(whole) == 1:
            return whole[0]
    if not found:
        raise DataError(f"{name} holds no input the app knows: expected {ACCEPTED}")
    if len(found) > 1:
        names = ", ".join(o.path.relative_to(folder).as_posix() for o in found[:3])
        raise DataError(f"{name} holds {len(found)} inputs ({names}{', ...' if len(found) > 3 else ''}); "
                        "upload one object at a time")
    return found[0].path


def stage_upload(file: str | Path, staging_root: Path, max_bytes: int) -> Upload:
    """Take in the uploaded ``file``: an image is copied, a zip unpacked, each into a fresh folder below
    ``staging_root``; the result names the input to train on. Nothing is left behind on a refusal."""
    file = Path(file)
    name = file.name
    if not file.is_file():
        raise DataError("no file was uploaded")
    size = file.stat().st_size
    if size == 0:
        raise DataError(f"{name} is empty")
    if size > max_bytes:
        raise DataError(f"{name} is {_megabytes(size)}; the app takes uploads up to {_megabytes(max_bytes)} "
                        "(va-app --max-upload-mb)")
    suffix = file.suffix.lower()
    if suffix not in (*IMAGE_SUFFIXES, *VIDEO_SUFFIXES, ".zip"):
        raise DataError(f"{name} is neither {ACCEPTED}")
    staging = Path(staging_root) / uuid.uuid4().hex
    upload = Upload(name, staging / name, staging)
    try:
        staging.mkdir(parents=True)
        if suffix == ".zip":
            unpacked = staging / (file.stem or "upload")
            _unpack(file, unpacked, max_bytes, name)
            check_confined(unpacked, name)
            upload.path = _object_in(unpacked, name)
        elif suffix in VIDEO_SUFFIXES:
            shutil.copyfile(file, upload.path)
            read_video(upload.path)  # a clear line for a video OpenCV cannot decode
        else:
            shutil.copyfile(file, upload.path)
            if image_shape(upload.path) is None:
                raise DataError(f"{name} is not a readable image (corrupt, truncated, or another kind of file)")
    except VAError as exc:
        upload.discard()
        raise type(exc)(upload.tell(str(exc))) from None
    except BaseException:
        upload.discard()
        raise
    return upload


def parse_views(choice: str | int | None) -> int | str:
    """The page's view choice as :func:`~va_plugin.api.reconstruct` takes it."""
    text = str(choice if choice is not None else "all").strip()
    return check_views(int(text) if text.isdigit() else text)


def _as_uint8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def inspect_upload(upload: Upload, method: str, quality: str = "default", views: int | str = "all"
                   ) -> tuple[Inspection, int | str]:
    """Read ``upload`` as training will (``views`` of a SyncDreamer strip; all views otherwise), checking
    the rig against the masks: what it holds, and the views option that applies to it."""
    if quality not in QUALITIES:
        raise ConfigError(f"quality {quality!r} is not one of {', '.join(QUALITIES)}")
    notes = []
    try:
        data_format = detect_format(upload.path)
        if views != "all" and data_format != "syncdreamer":
            notes.append(f"a view count applies to SyncDreamer strips only; training on every view of this "
                         f"{FORMAT_NAMES.get(data_format, data_format)}")
            views = "all"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            config = build_config(method, upload.path, preset=QUALITIES[quality], views=views, progress=False)
            parser = config.pipeline.datamanager.dataparser.setup()
            train = parser.get_outputs("train")
            held_out = parser.get_outputs("test")
        notes.extend(upload.tell(str(w.message)) for w in caught)
    except VAError as exc:
        raise type(exc)(upload.tell(str(exc))) from None
    if train is None or len(train) == 0:
        raise DataError(f"{upload.name} has no training views")
    images, masks = train.images.numpy(), train.masks
    masks = np.ones_like(images[..., :1]) if masks is None else masks.numpy()
    names = train.metadata.get("view_names") or []
    ids = train.metadata.get("view_ids") or list(range(len(train)))
    gallery = []
    for k in range(len(train)):
        view = ids[k] if k < len(ids) else k
        name = Path(upload.tell(str(names[view]))).name if view < len(names) else ""  # a file, or "x.png view k"
        caption = f"view {view}" + (f" ({name})" if name and not name.endswith(f"view {view}") else "")
        gallery.append((_as_uint8(mask_picture(images[k:k + 1], masks[k:k + 1], columns=1)), caption))
    source = train.metadata.get("mask_source", "alpha channel" if train.masks is not None else "none (no masks)")
    inspection = Inspection(format=data_format, views=len(train), total_views=len(train) + len(held_out or []),
                            masks=source, view_size=(train.cameras.width, train.cameras.height), gallery=gallery,
                            notes=notes)
    return inspection, views
