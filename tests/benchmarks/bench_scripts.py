"""Loading the benchmark scripts (``benchmarks/`` is a folder of scripts, not a package). Not a conftest.py:
the top-level tests/conftest.py is imported as ``conftest`` by other test modules."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_script_{name}", BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def scripts():
    return {name: load_script(f"run_{name}") for name in ("table1", "views", "ablation", "sweep")}
