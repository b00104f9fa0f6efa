"""Benchmark presets: which scenes, how long each run trains, and how it is evaluated.

``smoke`` checks the plumbing (the test suite runs it); ``quick`` gives a first paired comparison on three
level-2 scenes; ``gso10`` and ``full`` follow the paper's Sec. 4.1 with each method's default budget.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from va_plugin.errors import ConfigError
from va_plugin.export.config import ExportConfig

BACKBONES: dict[str, tuple[str, str]] = {"neus": ("neus", "va-neus"), "ngp": ("ngp", "va-ngp")}
"""backbone -> (original method, view-adaptive method), as registered."""

BACKBONE_TITLES = {"neus": "NeuS", "ngp": "InstantNGP"}


@dataclass(frozen=True)
class EvalSettings:
    """Arguments of :func:`va_plugin.eval.evaluate.evaluate_run` (the evaluation behind ``va-eval``)."""

    image_scale: float = 1.0  # held-out views (and their ground truth) at this fraction of the scene's size
    max_views: int | None = None  # held-out views scored (the first ones; None: all)
    mesh_resolution: int = ExportConfig.mesh_resolution  # marching-cubes grid of the run's mesh
    n_samples: int = 100_000  # surface samples per mesh for Chamfer distance and F-score


@dataclass
class BenchPreset:
    name: str
    description: str
    scenes: tuple[str, ...]  # of run_table1 and run_ablation (names as ``--scenes`` takes them)
    axis_scenes: tuple[str, ...]  # of run_views and run_sweep (4 runs per method and scene)
    evaluation: EvalSettings
    resolution: int = 256  # image side of the scenes (the paper's 256)
    scene_mesh_resolution: int = 160  # marching-cubes grid of the procedural objects' ground truth
    level: int = 2  # inconsistency level (2: calibrated to real SyncDreamer outputs)
    views: int = 4  # input views (the paper's 4)
    method_preset: str | None = None  # registry preset of every method (None: each method's default)
    steps: dict[str, int] = field(default_factory=dict)  # step budget per backbone (missing: the method's)
    # config overrides per backbone ("*": every backbone), for original and adaptive alike
    overrides: dict[str, tuple[str, ...]] = field(default_factory=dict)
    curve_points: int = 4  # checkpoints evaluated along each run (the last is the row itself)
    view_counts: tuple[int, ...] = (4, 8, 12, 16)  # input view counts of run_views (the paper's Fig. 5)
    levels: tuple[int, ...] = (0, 1, 2, 3)  # inconsistency levels of run_sweep

    def overrides_for(self, backbone: str) -> tuple[str, ...]:
        return tuple(self.overrides.get("*", ())) + tuple(self.overrides.get(backbone, ()))


PRESETS: dict[str, BenchPreset] = {
    "smoke": BenchPreset(
        name="smoke",
        description="plumbing check: one 32-px scene, 3 steps per run, tiny evaluation (under 2 minutes)",
        scenes=("mug",), axis_scenes=("mug",), resolution=32, scene_mesh_resolution=48,
        steps={"neus": 3, "ngp": 3},
        overrides={"*": ("pipeline.datamanager.rays_per_batch=32",),
                   "neus": ("pipeline.model.n_samples=8", "pipeline.model.n_importance=8"),
                   # 3 steps leave no density above the default threshold: without this there is no mesh
                   "ngp": ("pipeline.model.n_samples=16", "pipeline.model.density_threshold=0.5")},
        # LPIPS-Alex needs at least 31 px, hence 32-px scenes rather than 16
        evaluation=EvalSettings(image_scale=1.0, max_views=1, mesh_resolution=24, n_samples=2000),
        curve_points=2, view_counts=(4, 8), levels=(0, 2)),
    "quick": BenchPreset(
        name="quick",
        description="three level-2 procedural scenes at 256 px, each method's 'fast' preset "
                    "(target 20 minutes on 2 idle cores)",
        scenes=("mug", "knot", "chair"), axis_scenes=("mug",), method_preset="fast",
        evaluation=EvalSettings(image_scale=0.25, max_views=4, mesh_resolution=96, n_samples=100_000),
        curve_points=3),
    "gso10": BenchPreset(
        name="gso10",
        description="the 10 Google Scanned Objects under --data-root, 4 views at 256 px, each method's default "
                    "budget, every held-out view at full size, the final state only "
                    "(benchmarks/run_backbone.py; hours)",
        scenes=("gso",), axis_scenes=("gso",),
        evaluation=EvalSettings(image_scale=1.0, max_views=None, n_samples=100_000),
        # scoring 12 views at 256 px costs about as much as training: only the final state
        curve_points=1),
    "full": BenchPreset(
        name="full",
        description="every procedural object and every GSO object under --data-root, each method's default "
                    "budget (hours)",
        scenes=("procedural", "gso"), axis_scenes=("mug", "knot", "robot", "gso:alarm", "gso:lion"),
        evaluation=EvalSettings(image_scale=0.5, max_views=None, n_samples=100_000),
        curve_points=5),
}


def get_preset(name: str) -> BenchPreset:
    if name not in PRESETS:
        raise ConfigError(f"unknown benchmark preset {name!r}; known: {', '.join(PRESETS)}")
    return PRESETS[name]
