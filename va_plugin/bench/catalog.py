"""Scenes of a benchmark: names on the command line, and the scene cache under ``--out``.

A scene name is ``NAME`` or ``procedural:NAME``, ``gso:NAME`` (under ``--data-root``), ``mesh:PATH``, or
a group, ``procedural`` or ``gso``. Scenes are built once into
``CACHE/<name>-l<level>-v<views>-r<resolution>-s<seed>`` (through a temporary folder) and reused.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from va_plugin.bench.scenes import build_scene, gso, list_objects
from va_plugin.bench.scenes.inconsistency import KINDS
from va_plugin.errors import ConfigError, DataError

SCENE_FILE = "scene.json"
DATA_ROOT = Path(__file__).resolve().parents[3] / "shared" / "data"
"""``../shared/data`` beside the repository, where the benchmarks read their inputs by default."""
DEFAULT_GSO_ROOT = DATA_ROOT / "gso"
"""The Google Scanned Objects (``--data-root`` of the scene builder and the experiment scripts)."""
DEFAULT_GENERATED_ROOT = DATA_ROOT / "generated"
"""Real generator outputs, one folder per generator (``--data-root`` of the scripts that run them)."""


def generator_outputs(root: Path, folders: bool = True) -> list[tuple[str, Path]]:
    """``(name, path)`` of every generator output in ``root``'s generator folders, sorted: the PNG files
    and, with ``folders``, the folders (Wonder3D's layout). ConfigError when ``root`` is no folder."""
    if not Path(root).is_dir():
        raise ConfigError(f"no generator outputs at {root} (pass --data-root)")
    return [(item.stem, item) for sub in sorted(p for p in Path(root).iterdir() if p.is_dir())
            for item in sorted(sub.iterdir()) if item.suffix.lower() == ".png" or (folders and item.is_dir())]


@dataclass(frozen=True)
class SceneSpec:
    """One benchmark scene: a source plus the builder's arguments."""

    source: str
    level: int = 2
    views: int = 4
    resolution: int = 256
    seed: int = 42
    mesh_resolution: int = 160
    kinds: tuple[str, ...] = KINDS  # the inconsistency kinds injected (canonical order)

    @property
    def kinds_suffix(self) -> str:
        """Empty for all kinds, else ``+kind+kind`` (``+none`` for no kind), so rows and caches never mix."""
        if tuple(self.kinds) == KINDS:
            return ""
        return "+" + "+".join(self.kinds or ("none",))

    @property
    def name(self) -> str:
        """Short name for tables: the object's name (``gso-`` in front for GSO objects) + kinds suffix."""
        kind, _, rest = self.source.partition(":")
        if kind == "procedural":
            base = rest
        elif kind == "mesh":
            base = Path(rest).stem
        else:
            base = f"{kind}-{rest}"
        return base + self.kinds_suffix

    @property
    def folder_name(self) -> str:
        slug = re.sub(r"[^A-Za-z0-9_.+-]+", "_", self.name)
        return f"{slug}-l{self.level}-v{self.views}-r{self.resolution}-s{self.seed}"


def expand_scene_names(names: Iterable[str], data_root: Path | None) -> list[str]:
    """Scene names -> builder sources (``procedural:NAME``, ``gso:NAME``, ``mesh:PATH``), groups expanded,
    duplicates dropped. The ``gso`` group is empty (with a note on stdout) when ``data_root`` holds none."""

    procedural = [name for name, _ in list_objects()]
    sources: list[str] = []
    for raw in names:
        name = raw.strip()
        if not name:
            continue
        if name == "procedural":
            sources += [f"procedural:{n}" for n in procedural]
        elif name == "gso":
            try:
                sources += [f"gso:{n}" for n in gso.list_objects(Path(data_root))] if data_root else []
            except DataError as exc:
                print(f"note: no GSO scenes ({exc})", flush=True)
        elif ":" in name:
            kind, rest = name.split(":", 1)
            if kind not in ("procedural", "gso", "mesh"):
                raise ConfigError(f"scene {name!r}: the source kind must be procedural, gso or mesh")
            if kind == "gso":  # refuse a missing object now, not hours into a benchmark
                if data_root is None:
                    raise ConfigError(f"scene {name!r} needs --data-root, the folder of the GSO objects")
                gso.object_dir(Path(data_root), rest)
            sources.append(name)
        elif name in procedural:
            sources.append(f"procedural:{name}")
        else:
            raise ConfigError(f"unknown scene {name!r}; procedural objects: {', '.join(procedural)}; "
                              "or gso:NAME, mesh:PATH, and the groups procedural and gso")
    return list(dict.fromkeys(sources))


def ensure_scene(spec: SceneSpec, cache: Path, data_root: Path | None) -> Path:
    """The scene's folder in ``cache``, built first when it is not there yet."""

    out = Path(cache) / spec.folder_name
    if (out / SCENE_FILE).is_file():
        return out
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    build_scene(partial, spec.source, n_views=spec.views, level=spec.level, kinds=spec.kinds, seed=spec.seed,
                resolution=spec.resolution, data_root=data_root, mesh_resolution=spec.mesh_resolution)
    shutil.rmtree(out, ignore_errors=True)
    partial.rename(out)
    return out


def input_error(scene_dir: Path) -> dict:
    """The size of a scene's injected errors, from its ``scene.json``: ``input_psnr``, the mean PSNR (dB)
    of the perturbed inputs against their clean renders (100 at level 0), and ``input_rmse``, the mean
    over all input views of 10^(-PSNR/20) (clean views count 0: the paper's Lemma 1 (1/n) sum ||delta_i||)."""
    info = json.loads((Path(scene_dir) / SCENE_FILE).read_text())
    inconsistency = info["inconsistency"]
    per_view: Sequence[dict] = inconsistency["per_view"]
    rmse = [0.0 if not view["perturbed"] else 10.0 ** (-float(view["psnr"]) / 20.0) for view in per_view]
    return {"input_psnr": round(float(inconsistency["mean_psnr"]), 3),
            "input_rmse": round(math.fsum(rmse) / max(len(rmse), 1), 5)}
