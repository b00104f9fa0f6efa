"""Build a benchmark scene: clean held-out views, (in)consistent input views, ground-truth mesh.

    python benchmarks/build_scene.py --source procedural:mug --level 2 --out scenes/mug_l2 \
        [--views 4] [--kinds geometric,appearance,pose] [--seed 42] [--resolution 256] \
        [--figure benchmarks/figures/inputs_level2.png]
    python benchmarks/build_scene.py --source gso:alarm --data-root ../shared/data/gso --out scenes/alarm
    python benchmarks/build_scene.py --out scenes/spot \
        --source mesh:../shared/data/meshes/spot/spot_triangulated_good.obj
    python benchmarks/build_scene.py --list

Sources: ``procedural:NAME`` (see --list), ``mesh:PATH`` (a textured mesh file; --up and --yaw orient it),
``gso:NAME`` (a Google Scanned Object under --data-root). The scene layout and scene.json are described in
``va_plugin/data/scenes/builder.py``; the inconsistency kinds and levels in ``inconsistency.py``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from va_plugin.bench.catalog import DEFAULT_GSO_ROOT
from va_plugin.bench.scenes import build_scene, gso, inputs_figure, list_objects
from va_plugin.bench.scenes.inconsistency import KINDS, parse_level
from va_plugin.cli.common import friendly_errors
from va_plugin.errors import ConfigError, DataError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="procedural:mug", help="procedural:NAME | mesh:PATH | gso:NAME")
    parser.add_argument("--data-root", type=Path, default=DEFAULT_GSO_ROOT,
                        help="folder of the GSO objects (default ../shared/data/gso)")
    parser.add_argument("--views", default="4", help="input views, uniform in azimuth from view 0 (4/8/12/16)")
    parser.add_argument("--level", default="2", help="inconsistency level 0 (none) to 3 (strong)")
    parser.add_argument("--kinds", default=",".join(KINDS), help="comma-separated subset of "
                        f"{','.join(KINDS)}, or none")
    parser.add_argument("--seed", default="42", help="seed of the inconsistency draws")
    parser.add_argument("--resolution", default="256", help="image side in pixels")
    parser.add_argument("--out", type=Path, help="scene folder to write")
    parser.add_argument("--figure", type=Path, help="also write a PNG: clean inputs on top, inputs below")
    parser.add_argument("--list", action="store_true", help="list the procedural (and found GSO) objects")
    parser.add_argument("--mesh-resolution", default="160", help="marching-cubes grid of procedural objects")
    parser.add_argument("--up", default="y", choices=("y", "z"), help="up axis of a mesh: file (default y)")
    parser.add_argument("--yaw", default="0", help="turn a mesh: source about z, degrees")
    parser.add_argument("--texture", type=Path, help="texture image of a mesh: source (default: found beside it)")
    parser.add_argument("--perturb-view0", action="store_true",
                        help="perturb view 0 too (by default it stays clean, as a generator's conditioning view)")
    return parser


def _number(value: str, name: str, kind=int):
    try:
        return kind(value)
    except ValueError:
        raise ConfigError(f"--{name} must be {'an integer' if kind is int else 'a number'}, got {value!r}") from None


def print_objects(data_root: Path) -> None:
    print("procedural objects (--source procedural:NAME):")
    for name, description in list_objects():
        print(f"  {name:8s} {description}")
    try:
        names = gso.list_objects(data_root)
    except DataError:
        return
    print(f"GSO objects in {data_root} (--source gso:NAME): {', '.join(names)}")


@friendly_errors
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.list:
        print_objects(args.data_root)
        return 0
    if args.out is None:
        raise ConfigError("--out is required: the scene folder to write")
    out = build_scene(args.out, args.source, n_views=_number(args.views, "views"), level=parse_level(args.level),
                      kinds=args.kinds, seed=_number(args.seed, "seed"),
                      resolution=_number(args.resolution, "resolution"), data_root=args.data_root,
                      mesh_resolution=_number(args.mesh_resolution, "mesh-resolution"),
                      perturb_first_view=args.perturb_view0, up_axis=args.up, yaw_deg=_number(args.yaw, "yaw", float),
                      texture=args.texture)
    info = json.loads((out / "scene.json").read_text())
    inc = info["inconsistency"]
    lpips = "n/a" if inc["mean_lpips"] is None else f"{inc['mean_lpips']:.3f}"
    print(f"wrote {out}: {info['source']}, {len(info['train_views'])} inputs, level {inc['level']} "
          f"({','.join(inc['kinds']) or 'none'}): mean PSNR {inc['mean_psnr']:.2f} dB, LPIPS {lpips} "
          f"over {inc['means_over']}")
    if args.figure is not None:
        print(f"figure: {inputs_figure(out, args.figure)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
