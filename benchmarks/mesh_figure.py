"""Grey shaded views of meshes, one row per mesh: compare reconstructions with the ground truth by eye.

    python benchmarks/mesh_figure.py OUT.png MESH [MESH ...] [--views 4] [--resolution 128]

Rows follow the order of the meshes; the views circle the object on the SyncDreamer orbit (30 deg).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from va_plugin.data.images import write_image
from va_plugin.eval.evaluate import load_mesh
from va_plugin.export.render import mesh_views


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("meshes", type=Path, nargs="+")
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--resolution", type=int, default=128)
    args = parser.parse_args(argv)
    for path in args.meshes:
        if not path.is_file():
            print(f"error: mesh not found: {path}", file=sys.stderr)
            return 2
    write_image(args.out, mesh_views([load_mesh(p) for p in args.meshes], args.views, args.resolution))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
