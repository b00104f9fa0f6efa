"""Files of a baked texture: the textured mesh (GLB, or OBJ with its MTL and PNG), a picture of the atlas
beside each view's weight map, and the bake's JSON record."""

from __future__ import annotations

import json
import uuid
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from va_plugin.data.images import write_image
from va_plugin.errors import VAError
from va_plugin.export.baked import BakeReport, TexturedMesh
from va_plugin.export.frame import apply_transform, frame_record, frame_record_path, frame_transform

TEXTURE_FORMATS = (".glb", ".obj")


def check_texture_output(path: Path) -> None:
    """Refuse a textured mesh's path whose suffix is not one of TEXTURE_FORMATS."""
    if Path(path).suffix.lower() not in TEXTURE_FORMATS:
        raise VAError(f"a textured mesh is written as {' or '.join(TEXTURE_FORMATS)}, not {Path(path).suffix!r}")


def write_textured_mesh(textured: TexturedMesh, path: Path, frame: str = "upright") -> list[Path]:
    """GLB with the texture embedded, or OBJ with its ``.mtl`` and ``.png`` beside it (same stem), in
    ``frame`` (:mod:`va_plugin.export.frame`; only the vertices move, the UVs and the texture stay), with
    ``<stem>_frame.json`` (the transform from the training frame) last. Every file is written under a
    temporary name first and renamed at the end, so a failure leaves nothing half-written."""
    path = Path(path)
    check_texture_output(path)
    transform = frame_transform(textured.vertices, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh = replace(textured, vertices=apply_transform(textured.vertices, transform)).to_trimesh()
    staged: dict[Path, bytes] = {}
    if path.suffix.lower() == ".glb":
        staged[path] = mesh.export(file_type="glb")
    else:
        from trimesh.exchange.obj import export_obj

        text, files = export_obj(mesh, include_normals=True, include_color=False, include_texture=True,
                                 return_texture=True, mtl_name=path.stem + ".mtl")
        for name, data in files.items():
            if name.lower().endswith(".mtl"):
                mtl = data.decode() if isinstance(data, bytes) else data
                for other in files:
                    if not other.lower().endswith(".mtl"):
                        mtl = mtl.replace(other, path.stem + Path(other).suffix)
                staged[path.with_suffix(".mtl")] = mtl.encode()
            else:
                staged[path.with_name(path.stem + Path(name).suffix)] = data
        staged[path] = text.encode()
    staged[frame_record_path(path)] = json.dumps(frame_record(frame, transform), indent=2).encode()
    temporary = {}
    try:
        for target, data in staged.items():
            tmp = target.with_name(f"{target.name}.{uuid.uuid4().hex[:12]}.tmp")  # a write shares no temporary
            tmp.write_bytes(data)
            temporary[target] = tmp
        for target, tmp in temporary.items():
            tmp.replace(target)
    finally:
        for tmp in temporary.values():
            tmp.unlink(missing_ok=True)
    return list(staged)


def bake_picture(textured: TexturedMesh, report: BakeReport, path: Path, tile: int = 256) -> Path:
    """The atlas next to each view's weight map (white: that view gives the texel its whole color)."""
    tiles = [cv2.resize(textured.image, (tile, tile), interpolation=cv2.INTER_AREA)]
    for m in report.weight_maps:
        small = cv2.resize(m, (tile, tile), interpolation=cv2.INTER_AREA)
        tiles.append(np.repeat(small[..., None], 3, -1))
    per_row = min(len(tiles), 5)
    while len(tiles) % per_row:
        tiles.append(np.ones_like(tiles[0]))
    rows = [np.concatenate(tiles[i:i + per_row], 1) for i in range(0, len(tiles), per_row)]
    write_image(Path(path), np.concatenate(rows, 0))
    return Path(path)


def write_bake_record(report: BakeReport, path: Path, extra: dict[str, object] | None = None) -> Path:
    """The bake's summary (:meth:`BakeReport.summary`) and ``extra`` as JSON at ``path``."""
    record = {**report.summary(), **(extra or {})}
    Path(path).write_text(json.dumps(record, indent=2))
    return Path(path)
