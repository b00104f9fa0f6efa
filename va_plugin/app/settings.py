"""What ``va-app`` was started with: where it serves, where runs go, the upload limit, and the runs' options."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

from va_plugin.api import RECOMMENDED_METHOD
from va_plugin.errors import ConfigError
from va_plugin.export.config import ExportConfig
from va_plugin.registry import discover_methods

DEFAULT_RUNS = Path("outputs") / "app"


@dataclass
class RunOptions:
    """What every run of the server is given besides its input, quality and views (the sizes default to
    ``va-recon``'s)."""

    method: str = RECOMMENDED_METHOD
    """Reconstruction method."""
    device: str = "auto"
    """Where runs train: auto, cpu or cuda[:N]."""
    steps: int | None = None
    """Training steps (None: the quality's own budget)."""
    overrides: list[str] = field(default_factory=list)
    """Config overrides (``KEY=VALUE``, as ``va-recon --set``)."""
    texture_size: int = ExportConfig.texture_size
    """Side of the baked texture, in texels."""
    mesh_resolution: int = ExportConfig.mesh_resolution
    """Marching-cubes grid of the mesh."""
    turntable_frames: int = 36
    """Frames of the turntable video."""
    preview_every: int = 250
    """Training steps between two preview renders (0: none)."""
    preview_size: int = 128
    """Side of a preview render, in pixels."""
    threads: int = 0
    """CPU threads of a run's torch (0: torch's default)."""

    def export(self) -> ExportConfig:
        """The mesh and texture options of a run (the rest: :class:`ExportConfig`'s defaults, as ``va-recon``)."""
        return ExportConfig(mesh_resolution=self.mesh_resolution, texture_size=self.texture_size)

    def run_options(self) -> RunOptions:
        """These options alone (of a :class:`AppSettings`, say)."""
        return RunOptions(**{f.name: getattr(self, f.name) for f in fields(RunOptions)})


@dataclass
class AppSettings(RunOptions):
    """The server's options (``va-app --help``): where it serves, where runs go, and the runs' options."""

    runs: Path = DEFAULT_RUNS
    """Root of the run folders: one fresh folder per run below it."""
    host: str = "127.0.0.1"
    """Address the page is served on (0.0.0.0: every interface)."""
    port: int | None = None
    """Port of the page (None: the first free one from 7860)."""
    share: bool = False
    """Ask Gradio for a public link (needs the network)."""
    max_upload_mb: float = 100.0
    """Largest upload taken, in MB (a zip's unpacked size may be ten times that)."""
    warm_worker: bool = True
    """Keep a job process started ahead, so a job does not wait for its imports."""

    def validate(self) -> AppSettings:
        """Refuse options that cannot work (one line each), before the server starts."""
        if self.method not in discover_methods():
            raise ConfigError(f"unknown method {self.method!r}; known methods: {', '.join(discover_methods())}")
        if self.steps is not None and self.steps < 1:
            raise ConfigError(f"--steps must be at least 1, got {self.steps}")
        if self.max_upload_mb <= 0:
            raise ConfigError(f"--max-upload-mb must be positive, got {self.max_upload_mb:g}")
        self.export().validate()
        if self.turntable_frames < 1:
            raise ConfigError(f"--turntable-frames must be at least 1, got {self.turntable_frames}")
        if self.preview_every < 0 or self.preview_size < 8:
            raise ConfigError("--preview-every must be 0 or more and --preview-size at least 8")
        if self.threads < 0:
            raise ConfigError(f"--threads must be 0 (torch's default) or more, got {self.threads}")
        if self.port is not None and not 0 < self.port < 65536:
            raise ConfigError(f"--port must be between 1 and 65535, got {self.port}")
        return self

    @property
    def max_upload_bytes(self) -> int:
        return int(self.max_upload_mb * 1e6)
