"""Let ``import torchvision`` work beside the CPU build of torch, in the nerfstudio environment only.

PyPI's Linux wheels of torchvision are linked against the CUDA build of torch, so their C++ operators do not
load beside the CPU build; torchvision's ``_meta_registrations`` then fails on import, registering shapes
for operators that were never defined (``operator torchvision::nms does not exist``). nerfstudio imports
torchvision for its image utilities, which are pure Python.

``--install`` writes a start-up hook into the environment's site-packages (a ``.pth`` line and a small
module) that stands an empty module in for ``torchvision._meta_registrations``. Nothing else changes:
torchvision's C++ operators (nms, roi_align, deform_conv2d) stay unavailable, as they already were, and
nerfstudio's training path does not call them. ``--check`` imports torchvision and nerfstudio's pipeline.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import sysconfig
from pathlib import Path

MODULE = "va_torchvision_cpu_hook"
HOOK = '''"""Written by va-plugin's scripts/nerfstudio_torchvision_hook.py: see that file for why."""
import sys
import types

if "torchvision._meta_registrations" not in sys.modules:
    _stub = types.ModuleType("torchvision._meta_registrations")
    _stub.__doc__ = "empty: torchvision's C++ operators do not load beside the CPU build of torch"
    sys.modules["torchvision._meta_registrations"] = _stub
'''


def install() -> Path:
    site = Path(sysconfig.get_paths()["purelib"])
    (site / f"{MODULE}.py").write_text(HOOK, encoding="utf-8")
    pth = site / f"{MODULE}.pth"
    pth.write_text(f"import {MODULE}\n", encoding="utf-8")
    return pth


def check() -> None:
    code = "import torchvision.utils, nerfstudio.pipelines.base_pipeline; print(torchvision.__version__)"
    subprocess.run([sys.executable, "-c", code], check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--install", action="store_true", help="write the hook into this Python's site-packages")
    args = parser.parse_args()
    if args.install:
        print(f"wrote {install()}")
    check()


if __name__ == "__main__":
    main()
