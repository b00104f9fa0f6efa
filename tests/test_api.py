"""The Python API: the documented example runs, the calls give what the commands give, progress and
interrupts reach the caller."""

import functools
import re
import threading
import time
import warnings

import pytest
from conftest import REPO, write_syncdreamer_strip

import va_plugin
from va_plugin import api
from va_plugin.cli import recon
from va_plugin.cli import train as train_cli
from va_plugin.config import config_digest
from va_plugin.engine.options import override_list
from va_plugin.errors import ConfigError
from va_plugin.utils.threads import training_in_this_thread

TINY = {"pipeline.datamanager.rays_per_batch": 32, "pipeline.model.n_samples": 8, "pipeline.model.n_importance": 8,
        "pipeline.model.crossings_samples": 16}
SMALL_EXPORT = {"texture_size": 64, "mesh_resolution": 32, "turntable_frames": 2}


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    return write_syncdreamer_strip(tmp_path_factory.mktemp("api") / "strip.png", tile=32)


def _shrunk(monkeypatch):
    """Every call of the API shrunk to a few tiny steps (the documented calls, with test sizes)."""
    build = api.build_config

    def tiny_build(*args, **kwargs):
        overrides = override_list(kwargs.pop("overrides", None))
        kwargs.update(steps=2, device="cpu")
        return build(*args, overrides=[*overrides, *override_list(TINY)], **kwargs)

    reconstruct = api.reconstruct
    monkeypatch.setattr(api, "build_config", tiny_build)
    monkeypatch.setattr(api, "reconstruct", functools.partial(reconstruct, **SMALL_EXPORT))


def test_the_documented_example_runs(strip, tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", (REPO / "docs" / "python.md").read_text(), re.S)
    assert len(blocks) >= 3
    (tmp_path / "strip.png").write_bytes(strip.read_bytes())
    monkeypatch.chdir(tmp_path)
    _shrunk(monkeypatch)
    namespace = {}
    for block in blocks:
        exec(compile(block, "docs/python.md", "exec"), namespace)
    printed = capsys.readouterr().out
    assert "runs/strip/mesh.glb" in printed and (tmp_path / "runs/strip/summary.json").is_file()
    assert (tmp_path / "runs/strip-neus/mesh.glb").is_file() and (tmp_path / "runs/strip-views/mesh.ply").is_file()
    assert "step 2/2: loss" in printed
    assert "lowest point at y = 0.000000" in printed and (tmp_path / "runs/strip-neus/mesh.obj").is_file()


def test_reconstruct_writes_what_va_recon_writes(strip, tmp_path):
    options = ["--steps", "3", "--seed", "7", "--device", "cpu", "--texture-size", "64", "--mesh-resolution", "32",
               "--turntable-frames", "2"]
    for key, value in TINY.items():
        options += ["--set", f"{key}={value}"]
    assert recon.main([str(strip), "--out", str(tmp_path / "cli"), *options]) == 0
    result = va_plugin.reconstruct(strip, tmp_path / "api", steps=3, seed=7, device="cpu", overrides=TINY,
                                   **SMALL_EXPORT)
    for name in ("mesh.ply", "mesh.glb", "mesh_bake.png"):
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "api" / name).read_bytes(), name
    assert result.mesh == tmp_path / "api" / "mesh.ply" and result.textured_mesh == tmp_path / "api" / "mesh.glb"
    assert result.steps == 3 and result.views == 16 and result.turntable.is_file() and result.summary.is_file()
    assert result.record["resumed_from_step"] is None and result.config.seed == 7


def test_build_config_is_the_config_va_train_builds(strip, tmp_path):
    argv = ["neus", "--data", str(strip), "--views", "8", "--preset", "fast", "--steps", "9", "--seed", "3",
            "--output-dir", str(tmp_path), "--set", "pipeline.model.eikonal_weight=0.05"]
    from_cli = train_cli.make_config(train_cli.build_parser(va_plugin.registry.discover_methods()).parse_args(argv))
    from_api = va_plugin.build_config("neus", strip, views=8, preset="fast", steps=9, seed=3, out=tmp_path,
                                      overrides={"pipeline__model__eikonal_weight": 0.05})
    assert config_digest(from_cli) == config_digest(from_api)
    assert from_api.pipeline.datamanager.dataparser.num_views == 8 and from_api.pipeline.model.eikonal_weight == 0.05


@pytest.mark.parametrize("kwargs, message", [
    ({"method": "nerf"}, "unknown method 'nerf'"),
    ({"steps": 0}, "--steps must be at least 1"),
    ({"views": 5}, "views 5 is not one of"),
    ({"overrides": {"pipeline.model.eikonal_weigth": 1}}, "did you mean pipeline.model.eikonal_weight"),
    ({"data_format": "obj"}, "unknown data format 'obj'"),
])
def test_bad_options_raise_one_line(strip, kwargs, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        va_plugin.build_config(**{"method": "neus", "data": strip, **kwargs})


def test_a_face_count_no_mesh_can_have_is_refused_before_training(strip, tmp_path, capsys):
    started = time.perf_counter()
    with pytest.raises(ConfigError, match="--faces 1000000000 is more than a mesh here can have"):
        va_plugin.reconstruct(strip, out=tmp_path / "out", faces=1_000_000_000)
    assert recon.main([str(strip), "--out", str(tmp_path / "out"), "--faces", "1000000000"]) == 2
    assert "at most about 2000000" in capsys.readouterr().err
    assert time.perf_counter() - started < 10 and not (tmp_path / "out").exists()


def test_progress_and_an_interrupt_reach_the_caller(strip, tmp_path):
    config = va_plugin.build_config("neus", strip, steps=4, device="cpu", out=tmp_path / "run", progress=False,
                                    overrides=TINY)
    config.checkpoint_every = 100
    seen = []

    def stop_at_two(step, total, losses):
        seen.append((step, total, "loss" in losses))
        if step == 2:
            raise KeyboardInterrupt

    with pytest.raises(va_plugin.TrainingInterrupted) as stop:
        va_plugin.train(config, progress=stop_at_two)
    assert stop.value.step == 2 and stop.value.checkpoint.is_file()
    assert seen == [(1, 4, True), (2, 4, True)]
    with pytest.raises(ConfigError, match="already holds a run"):
        va_plugin.train(config)
    run = va_plugin.train(config, resume=True, progress=lambda step, total, losses: seen.append((step, total)))
    assert seen[-2:] == [(3, 4), (4, 4)] and va_plugin.load_run(run).state["step"] == 4


def test_losses_given_to_progress(strip, tmp_path):
    config = va_plugin.build_config("neus", strip, steps=1, device="cpu", out=tmp_path, progress=False,
                                    overrides=TINY)
    got = []
    va_plugin.train(config, progress=lambda step, total, losses: got.append(losses))
    assert "loss" in got[0] and all(isinstance(v, float) for v in got[0].values())


def test_the_package_offers_the_api_lazily():
    assert set(va_plugin.API) <= set(dir(va_plugin))
    assert va_plugin.export_mesh is api.export_mesh
    with pytest.raises(AttributeError):
        va_plugin.no_such_function  # noqa: B018 (the attribute access is the test)


def test_a_call_training_beside_another_thread_is_warned_about():
    """Two runs in two threads of one process share torch's random generator: each is told, the one starting
    second at once and the other when it ends; one call alone, or calls one after another, hear nothing."""
    entered, leave = threading.Event(), threading.Event()

    def first():  # its warnings go to the main thread's record (warnings' state is the process's)
        with training_in_this_thread("train()"):
            entered.set()
            leave.wait(10)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with training_in_this_thread("reconstruct()"):
            pass
        assert caught == []
        other = threading.Thread(target=first)
        other.start()
        entered.wait(10)
        with training_in_this_thread("reconstruct()"):
            pass
        leave.set()
        other.join(10)
    ours = [str(w.message) for w in caught if "another thread" in str(w.message)]
    assert any(m.startswith("reconstruct() started while train() trains in another thread") for m in ours)
    assert any(m.startswith("train() trained while another call trained") for m in ours)


def test_an_interrupt_after_training_keeps_the_run_and_says_resume(strip, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    options = [str(strip), "--out", str(out), "--steps", "1", "--device", "cpu", "--no-texture",
               "--mesh-resolution", "16", "--quiet", *(f"--set={k}={v}" for k, v in TINY.items())]
    real = api.export_mesh

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(api, "export_mesh", ctrl_c)
    assert recon.main(options) == 130
    err = capsys.readouterr().err
    assert "interrupted after training (the run is kept: step 1" in err and "--resume" in err
    monkeypatch.setattr(api, "export_mesh", real)
    assert recon.main([*options, "--resume"]) == 0 and (out / "mesh.ply").is_file()
