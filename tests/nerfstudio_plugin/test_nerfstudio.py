"""The va methods inside nerfstudio (``make nerfstudio`` sets up its environment, ``make test-nerfstudio``
runs these there): registered with ns-train, a few CPU steps of each on a tiny SyncDreamer strip, the
export of the run, and the same losses as va-train's for the first steps."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import tiny_config, write_syncdreamer_strip

pytestmark = pytest.mark.skipif(importlib.util.find_spec("nerfstudio") is None,
                                reason="nerfstudio is not installed here (make nerfstudio sets up .venv-ns/)")

METHODS = {"va-neus": "va-neus", "va-ngp": "va-ngp", "va-plugin-neus": "neus"}
"""The names in nerfstudio -> ours."""
TINY = {"pipeline.datamanager.rays_per_batch": 32, "pipeline.model.n_samples": 8, "pipeline.model.n_importance": 8,
        "pipeline.model.eval_chunk": 256, "pipeline.model.crossings_rays": 8, "pipeline.model.crossings_samples": 16}
"""Our tiny sizes (tests/conftest.py's ``tiny_config``), as ns-train options where the model has them."""


@pytest.fixture(scope="module")
def strip(tmp_path_factory) -> Path:
    return write_syncdreamer_strip(tmp_path_factory.mktemp("strip") / "toy.png", tile=16)


def ns_options(method: str) -> list[str]:
    """ns-train options of a tiny CPU run of ``method`` (without the viewer's server)."""
    from va_plugin.registry import builtin_methods

    model = builtin_methods()[METHODS[method]].config.pipeline.model
    options = ["--machine.device-type", "cpu", "--vis", "tensorboard", "--viewer.quit-on-train-completion", "True"]
    for key, value in TINY.items():
        name = key.rsplit(".", 1)[-1]
        if key.startswith("pipeline.datamanager.") or hasattr(model, name):
            options += ["--" + key.replace("pipeline.model.", "pipeline.model.va.").replace("_", "-"), str(value)]
    if getattr(model.field, "has_view_branches", False) or hasattr(model.field, "diagnostics_scale"):
        options += ["--pipeline.model.va.field.diagnostics-scale", "0"]  # the pictures take minutes
    if hasattr(model.field, "skip_consistent_scenes"):
        options += ["--pipeline.model.va.field.skip-consistent-scenes", "False"]  # the toy's views agree
    return options


def test_methods_and_dataparser_are_registered():
    from nerfstudio.plugins.registry import discover_methods
    from nerfstudio.plugins.registry_dataparser import discover_dataparsers

    methods, descriptions = discover_methods()
    assert set(METHODS) <= set(methods) and all(descriptions[name].startswith("va-plugin") for name in METHODS)
    assert all(methods[name].method_name == name for name in METHODS)
    assert "va-generator" in discover_dataparsers()[0]
    assert methods["va-neus"].machine.device_type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert methods["va-neus"].viewer.websocket_host == "127.0.0.1"


@pytest.mark.parametrize("method", sorted(METHODS))
def test_ns_train_few_cpu_steps_then_export(method, strip, tmp_path):
    """ns-train runs 3 steps and writes both checkpoints; va-export makes the textured mesh of the run."""
    ns_train = Path(sys.executable).parent / "ns-train"
    command = [str(ns_train), method, "--max-num-iterations", "3", "--output-dir", str(tmp_path),
               "--timestamp", "run", *ns_options(method), "va-generator", "--data", str(strip)]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    run = tmp_path / "toy" / method / "run"
    assert (run / "config.yml").is_file() and list((run / "nerfstudio_models").glob("step-*.ckpt"))
    assert [p.name for p in (run / "checkpoints").glob("step-*.ckpt")] == ["step-0000003.ckpt"]
    if method.startswith("va-n"):  # the three phases, compressed into the 3 steps, in the log and on the console
        events = [json.loads(line).get("event", "") for line in (run / "metrics.jsonl").read_text().splitlines()]
        assert any("phase 2" in e for e in events) and any("phase 3" in e for e in events), events
        assert f"[{method}] step 2: phase 3: self-attention fusion" in result.stdout
    from va_plugin.api import load_run
    from va_plugin.cli.export import main as va_export

    loaded = load_run(run, "cpu")  # our checkpoint: the trained weights in our pipeline
    assert loaded.config.method_name == method and loaded.state["step"] == 3
    if "ngp" in method:  # 3 steps of a density field leave no surface to extract yet
        rays = loaded.pipeline.datamanager.next_train(0)[0]
        assert torch.isfinite(loaded.pipeline.model.render_rays(rays)["rgb"]).all()
        return
    assert va_export(["mesh", "--load-dir", str(run), "--texture", "--resolution", "24", "--texture-size", "64",
                      "--faces", "0", "--quiet"]) == 0
    assert (run / "mesh.glb").stat().st_size > 0 and (run / "mesh.obj").is_file()


@pytest.mark.parametrize("method", ["va-neus", "va-plugin-neus"])
def test_first_steps_losses_match_our_trainer(method, strip, tmp_path):
    """Same seed, same batch: nerfstudio's trainer and ours give the same loss terms, through the phase
    switches (4 steps: phases 1, 2, 3 with the schedules compressed)."""
    from va_plugin.config import apply_override
    from va_plugin.data.dataparsers import resolve_dataparser
    from va_plugin.nerfstudio.compare import largest_difference, ns_train_losses, va_train_losses
    from va_plugin.nerfstudio.methods import nerfstudio_config

    steps = 4
    ours = tiny_config(METHODS[method], strip, tmp_path / "ours", steps=steps)
    ours.pipeline.datamanager.dataparser = resolve_dataparser(strip)
    if hasattr(ours.pipeline.model.field, "diagnostics_scale"):
        apply_override(ours, "pipeline.model.field.diagnostics_scale=0")
    theirs = nerfstudio_config(method, METHODS[method])
    theirs.pipeline.schedule_steps = ours.schedule_steps
    theirs.output_dir, theirs.timestamp, theirs.vis = tmp_path / "ns", "run", "tensorboard"
    theirs.machine.device_type = "cpu"
    theirs.pipeline.datamanager.dataparser.data = strip
    theirs.pipeline.datamanager.rays_per_batch = ours.pipeline.datamanager.rays_per_batch
    theirs.pipeline.model.va = ours.pipeline.model
    expected = va_train_losses(ours, steps)
    got = ns_train_losses(theirs, steps)
    assert len(got) == steps and all(got) and largest_difference(expected, got) <= 1e-5, (expected, got)


def test_averaged_weights_match_our_trainer(strip, tmp_path):
    """With ``average_fraction`` both trainers end on the same mean of the last steps' weights."""
    from va_plugin.data.dataparsers import resolve_dataparser
    from va_plugin.nerfstudio.compare import ns_train
    from va_plugin.nerfstudio.methods import nerfstudio_config

    steps = 4
    ours = tiny_config("neus", strip, tmp_path / "ours", steps=steps)
    ours.pipeline.datamanager.dataparser = resolve_dataparser(strip)
    ours.average_fraction = 0.5
    trainer = ours.setup()
    trainer.train()
    theirs = nerfstudio_config("va-plugin-neus", "neus")
    theirs.pipeline.schedule_steps, theirs.pipeline.average_fraction = ours.schedule_steps, 0.5
    theirs.output_dir, theirs.timestamp, theirs.vis = tmp_path / "ns", "run", "tensorboard"
    theirs.machine.device_type = "cpu"
    theirs.pipeline.datamanager.dataparser.data = strip
    theirs.pipeline.datamanager.rays_per_batch = ours.pipeline.datamanager.rays_per_batch
    theirs.pipeline.model.va = ours.pipeline.model
    _, ns_trainer = ns_train(theirs, steps)
    expected, got = trainer.model.state_dict(), ns_trainer.pipeline.va.model.state_dict()
    assert trainer.average is not None and trainer.average.count == 2
    for name, value in expected.items():
        if value.is_floating_point():
            assert torch.allclose(got[name], value, atol=1e-5), name
    last = tiny_config("neus", strip, tmp_path / "last", steps=steps)  # the average differs from the last step
    last.pipeline.datamanager.dataparser = resolve_dataparser(strip)
    plain = last.setup()
    plain.train()
    assert any(not torch.allclose(plain.model.state_dict()[n], v, atol=1e-5) for n, v in expected.items()
               if v.is_floating_point())


def test_missing_input_is_one_error_line(tmp_path):
    """A bad input stops ns-train with our one-line error and exit status 2, not a traceback."""
    ns_train = Path(sys.executable).parent / "ns-train"
    command = [str(ns_train), "va-plugin-neus", "--output-dir", str(tmp_path), "--vis", "tensorboard",
               "--machine.device-type", "cpu", "va-generator", "--data", str(tmp_path / "missing.png")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 2, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1] == f"error: data not found: {tmp_path / 'missing.png'}"


@pytest.mark.parametrize("method", ["neus", "va-ngp"])
def test_field_answers_nerfstudio_samples(method, strip, tmp_path):
    """Our field behind nerfstudio's Field gives, at nerfstudio's samples, what our model reads there."""
    from nerfstudio.cameras.rays import RayBundle as NSRayBundle
    from nerfstudio.field_components.field_heads import FieldHeadNames
    from nerfstudio.model_components.ray_samplers import UniformSampler

    from va_plugin.data.dataparsers import resolve_dataparser
    from va_plugin.nerfstudio.field import VAField

    config = tiny_config(method, strip, tmp_path)
    config.pipeline.datamanager.dataparser = resolve_dataparser(strip)
    pipeline = config.pipeline.setup(device=torch.device("cpu"), schedule_steps=2)
    rays, _ = pipeline.datamanager.next_train(0)
    n = len(rays)
    bundle = NSRayBundle(origins=rays.origins, directions=rays.directions, pixel_area=torch.ones(n, 1),
                         camera_indices=rays.camera_indices[:, None], nears=torch.full((n, 1), 0.5),
                         fars=torch.full((n, 1), 2.0))
    samples = UniformSampler(num_samples=4)(bundle)
    field = VAField(pipeline.model.field)
    outputs = field(samples)
    positions = samples.frustums.get_positions().reshape(-1, 3)
    assert outputs[FieldHeadNames.RGB].shape == (n, 4, 3)
    assert ((outputs[FieldHeadNames.RGB] >= 0) & (outputs[FieldHeadNames.RGB] <= 1)).all()
    if pipeline.model.field.geometry_kind == "sdf":
        expected = pipeline.model.mesh_field(positions)
        assert torch.allclose(outputs[FieldHeadNames.SDF].reshape(-1), expected, atol=1e-6)
        assert torch.allclose(outputs[FieldHeadNames.NORMALS].norm(dim=-1), torch.ones(n, 4), atol=1e-4)
    else:
        expected = pipeline.model.density(positions)
        assert torch.allclose(outputs[FieldHeadNames.DENSITY].reshape(-1), expected, rtol=1e-5)
    assert list(field.parameters()) == []  # held, not registered: the weights stay saved once, under the model


def test_import_va_plugin_leaves_nerfstudio_alone():
    """Only nerfstudio's entry points import the plugin: our package and its API never import nerfstudio (nor
    torchvision: the environment's start-up hook only stands a stub in for one of its modules)."""
    code = ("import sys, va_plugin, va_plugin.api, va_plugin.cli.export, va_plugin.registry\n"
            "va_plugin.registry.discover_methods()\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'nerfstudio' or m == 'torchvision'))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip() == "[]"


def test_dataparser_gives_nerfstudio_the_same_rays_and_view_files(strip, tmp_path):
    """For nerfstudio's own methods: the views as RGBA files, and cameras whose rays are ours."""
    from va_plugin.nerfstudio.dataparser import VAGeneratorDataParserConfig

    parser = VAGeneratorDataParserConfig(data=strip, cache_dir=tmp_path / "cache").setup()
    outputs = parser.get_dataparser_outputs("train")
    ours = parser.va_outputs("train")
    assert len(outputs.image_filenames) == len(ours) == 16 and all(p.is_file() for p in outputs.image_filenames)
    assert parser.get_dataparser_outputs("train").image_filenames == outputs.image_filenames  # written once
    for view in (0, 5):
        theirs = outputs.cameras.generate_rays(camera_indices=view, keep_shape=True)
        origins, directions = ours.cameras.generate_rays(view, *ours.cameras.pixel_grid(view)[1:])
        assert torch.allclose(theirs.origins.reshape(-1, 3), origins, atol=1e-5)
        assert torch.allclose(torch.nn.functional.normalize(theirs.directions.reshape(-1, 3), dim=-1), directions,
                              atol=1e-5)
