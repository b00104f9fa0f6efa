"""va-plugin: view-adaptive NeRF/NeuS reconstruction from generated multi-view images."""

import runpy
from pathlib import Path

from setuptools import find_packages, setup

# the built-in methods are listed once, in method_configs/__init__.py (a file without imports)
BUILTIN_METHODS = runpy.run_path(
    str(Path(__file__).resolve().parent / "method_configs" / "__init__.py"))["BUILTIN_METHODS"]
METHODS = [f"{name} = {reference}" for name, reference in BUILTIN_METHODS.items()]
# va-app's web page; its tests (tests/app) drive it through gradio_client, which gradio brings
APP = ["gradio>=6,<7"]

setup(
    name="va-plugin",
    version="0.1.0",
    description="View-adaptive renderer for view-consistent 2D-to-3D generation (NeuS / InstantNGP plugin)",
    python_requires=">=3.11",
    packages=find_packages(include=["va_plugin", "va_plugin.*", "method_configs", "method_configs.*"]),
    # the hash grid's fused CPU kernels are compiled from source on first use
    package_data={"va_plugin.fields.encodings": ["*.cpp"], "va_plugin.data": ["rig_files/*.json"]},
    install_requires=[
        # torch is pinned by the setup script to the CPU build on this machine; a plain range here
        # would let pip pull a multi-GB CUDA build when torch is missing.
        "torch>=2.1",
        "numpy",
        "trimesh",
        "open3d",
        "opencv-contrib-python-headless",
        "scikit-image",  # marching cubes
        "tqdm",          # progress bars
        "xatlas",        # UV atlases of extracted meshes for baked textures (va-export mesh --texture)
        "ninja",         # builds the hash grid's fused CPU kernels (torch.utils.cpp_extension needs it)
    ],
    extras_require={
        "test": ["pytest", "hypothesis", "ruff", *APP],  # the linter that `make test` runs first is ruff
        "plots": ["matplotlib"],
        "ray": ["ray"],  # va-batch --engine ray
        "app": APP,  # va-app
    },
    entry_points={
        "console_scripts": [
            "va-train = va_plugin.cli.train:main",
            "va-export = va_plugin.cli.export:main",
            "va-eval = va_plugin.cli.eval:main",
            "va-demo = va_plugin.cli.demo:main",
            "va-recon = va_plugin.cli.recon:main",
            "va-batch = va_plugin.cli.batch:main",
            "va-app = va_plugin.cli.app:main",
        ],
        "va_plugin.methods": METHODS,
        # multi-view generator formats of other packages: a DataFormat, a rig dict or a rig file's path
        "va_plugin.formats": [],
        # nerfstudio's trainer (ns-train) lists these when nerfstudio is installed: make nerfstudio
        "nerfstudio.method_configs": [
            "va-neus = va_plugin.nerfstudio.methods:va_neus",
            "va-ngp = va_plugin.nerfstudio.methods:va_ngp",
            "va-plugin-neus = va_plugin.nerfstudio.methods:va_plugin_neus",
        ],
        "nerfstudio.dataparser_configs": ["va-generator = va_plugin.nerfstudio.dataparser:va_generator"],
    },
)
