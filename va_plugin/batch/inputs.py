"""Which objects a batch holds: the generator outputs and scene folders below a folder, or those a text
file lists, each with a unique name (its run folder's name).

Below a folder, an object is an image or video file or a folder a dataparser reads as a whole (a scene
folder, a Wonder3D or Era3D output); other folders are searched, hidden ones skipped (a folder of 4 images
or of 21 frames is searched too: name it in a list file to read it as one object). An image that fits no format is still
an object (its job fails, the batch goes on). A list file names one path per line, relative to the file's
folder (blank lines and ``#`` lines skipped).
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from va_plugin.data.dataparsers import is_input_folder
from va_plugin.data.dataparsers.generators import IMAGE_SUFFIXES
from va_plugin.data.images import VIDEO_SUFFIXES
from va_plugin.errors import ConfigError

MAX_DEPTH = 4
"""How many folder levels below INPUTS are searched for objects."""


@dataclass(frozen=True)
class BatchObject:
    """One object of a batch: its name (unique in the batch) and its input (an absolute path)."""

    name: str
    path: Path


INPUT_SUFFIXES = (*IMAGE_SUFFIXES, *VIDEO_SUFFIXES)
"""Files that are objects of a batch: generator images, and videos (SV3D)."""


def _search(folder: Path, depth: int) -> list[Path]:
    if is_input_folder(folder):
        return [folder]
    found: list[Path] = []
    for item in sorted(folder.iterdir()):
        if item.name.startswith("."):
            continue
        if item.is_file() and item.suffix.lower() in INPUT_SUFFIXES:
            found.append(item)
        elif item.is_dir() and depth < MAX_DEPTH:
            found.extend(_search(item, depth + 1))
    return found


def _read_list(list_file: Path) -> list[Path]:
    try:
        lines = list_file.read_text(encoding="utf-8").splitlines()
    except (UnicodeDecodeError, OSError) as exc:
        raise ConfigError(f"cannot read {list_file} as a list of paths ({type(exc).__name__})") from None
    paths = []
    for line in lines:
        line = line.strip()
        if line and not line.startswith("#"):
            path = Path(line).expanduser()
            paths.append(path if path.is_absolute() else list_file.parent / path)
    return paths


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-.") or "object"


def _names(paths: list[Path], root: Path) -> list[str]:
    """Each path's stem; where stems repeat, the path below ``root`` (or the whole path) joined by '-',
    and a counter where even that repeats."""
    stems = [_slug(p.stem if p.suffix.lower() in INPUT_SUFFIXES else p.name) for p in paths]
    repeated = Counter(stems)
    names = []
    for path, stem in zip(paths, stems):
        if repeated[stem] > 1:
            try:
                relative = path.relative_to(root)
            except ValueError:
                relative = Path(*path.parts[1:])
            stem = _slug("-".join(relative.with_suffix("").parts))
        names.append(stem)
    seen: Counter = Counter()
    unique = []
    for name in names:
        seen[name] += 1
        unique.append(name if seen[name] == 1 else f"{name}-{seen[name]}")
    return unique


def find_objects(inputs: Path) -> list[BatchObject]:
    """The objects of INPUTS (a folder, a list file, or one input), in a stable order."""
    inputs = Path(inputs).expanduser()
    if not inputs.exists():
        raise ConfigError(f"inputs not found: {inputs}")
    inputs = inputs.resolve()
    if inputs.is_dir():
        paths, root = _search(inputs, 0), inputs
    elif inputs.suffix.lower() in INPUT_SUFFIXES or inputs.suffix.lower() == ".json":
        paths, root = [inputs], inputs.parent
    else:
        paths, root = [p.resolve() for p in _read_list(inputs)], inputs.parent
    if not paths:
        raise ConfigError(f"no inputs in {inputs}: expected generator outputs (images such as SyncDreamer "
                          "strips or Zero123++ grids), scene folders with transforms.json, Wonder3D folders, "
                          "or a text file listing such paths")
    return [BatchObject(name, path) for name, path in zip(_names(paths, root), paths)]
