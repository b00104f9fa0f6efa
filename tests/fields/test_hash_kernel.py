"""The fused CPU kernels of the hash encoding against the PyTorch path they replace: the same encoding bit
for bit, the same gradients to float rounding, the same results on any thread count, and the fallbacks
(points that need gradients, the switch, a failed build)."""

import pytest
import torch

from va_plugin.fields.encodings import hash_kernel
from va_plugin.fields.encodings.hash_grid import HashGridEncoding

SMALL = dict(n_levels=8, n_features_per_level=2, log2_hashmap_size=12, base_resolution=4, max_resolution=128)


@pytest.fixture(scope="module")
def ops():
    built = hash_kernel.load_kernels()
    if built is None:
        pytest.skip("the fused hash kernels could not be built here (no C++ compiler or ninja)")
    return built


@pytest.fixture
def pytorch_path(monkeypatch):
    """A context in which the encoding takes the PyTorch path."""

    class Switch:
        def __enter__(self):
            monkeypatch.setenv(hash_kernel.ENV_SWITCH, "0")

        def __exit__(self, *exc):
            monkeypatch.delenv(hash_kernel.ENV_SWITCH)

    return Switch()


def _points(n: int, seed: int = 0) -> torch.Tensor:
    """Random points in and around [-1, 1]^3 plus the domain's corners and far-away points."""
    generator = torch.Generator().manual_seed(seed)
    inside = torch.rand(n, 3, generator=generator) * 2.4 - 1.2
    edges = torch.cartesian_prod(*[torch.tensor([-1.0, 1.0, 0.0, -5.0, 1e6])] * 3)
    return torch.cat([inside, edges])


def _training_step(encoding: HashGridEncoding, points: torch.Tensor, weights: torch.Tensor):
    """A hash SDF field's pattern: the encoding feeds a network whose input gradient is pulled back to the
    points, and a loss on both the output and that gradient (an eikonal term)."""
    encoded, pullback = encoding.forward_with_pullback(points)
    hidden = torch.tanh(encoded @ weights)
    grad_encoded = (1 - hidden.square()) @ weights.t()  # d sum(hidden) / d encoded
    normal = pullback(grad_encoded)
    loss = hidden.square().sum() + (normal.norm(dim=-1) - 1).square().mean()
    grads = torch.autograd.grad(loss, (encoding.table, weights))
    return encoded.detach(), normal.detach(), *grads


@pytest.mark.parametrize("features, active", [(2, 8), (2, 5), (1, 8), (4, 3)])
def test_the_encoding_is_the_same_bits_as_the_pytorch_path(ops, pytorch_path, features, active):
    encoding = HashGridEncoding(**{**SMALL, "n_features_per_level": features}, init_scale=1.0)
    encoding.set_active_levels(active)
    x = _points(3000)
    fused = encoding(x)
    with pytorch_path:
        plain = encoding(x)
    assert torch.equal(fused, plain)


def test_training_gradients_match_the_pytorch_path(ops, pytorch_path):
    """The table's and the network's gradients through both the encoding and its pull-back agree to float
    rounding; the encoding itself is the same bits."""
    encoding = HashGridEncoding(**SMALL, init_scale=0.1)
    generator = torch.Generator().manual_seed(1)
    weights = (torch.randn(encoding.output_dim, 8, generator=generator) * 0.5).requires_grad_()
    x = _points(2000)
    fused = _training_step(encoding, x, weights)
    with pytorch_path:
        plain = _training_step(encoding, x, weights)
    assert torch.equal(fused[0], plain[0])
    for a, b in zip(fused[1:], plain[1:]):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5 * b.abs().max().item())
    assert fused[2].abs().sum() > 0 and fused[3].abs().sum() > 0


@pytest.mark.parametrize("active", [3, 8])
def test_the_table_gradient_is_zero_outside_the_rows_it_reaches_whatever_the_memory_held(ops, pytorch_path, active):
    """The kernel zeroes each level's rows as it scatters into them (and the closed levels' rows with the
    last open one): memory that held NaN before gives the same gradient, exactly 0 on closed levels."""
    encoding = HashGridEncoding(**SMALL, init_scale=0.1)
    encoding.set_active_levels(active)
    x = _points(1500)
    grad_encoded = torch.randn(x.shape[0], encoding.output_dim, generator=torch.Generator().manual_seed(4))

    def table_grad():
        encoded, pullback = encoding.forward_with_pullback(x)
        loss = (encoded * grad_encoded).sum() + pullback(grad_encoded).square().sum()
        return torch.autograd.grad(loss, encoding.table)[0]

    first = table_grad()
    del first
    torch.full_like(encoding.table, float("nan"))  # freed at once: the next gradient may get its memory
    fused = table_grad()
    with pytorch_path:
        plain = table_grad()
    assert torch.isfinite(fused).all()
    torch.testing.assert_close(fused, plain, rtol=1e-5, atol=1e-5 * plain.abs().max().item())
    closed = encoding.offsets[active] if active < len(encoding.offsets) else fused.shape[-1]
    assert torch.equal(fused[:, closed:], torch.zeros_like(fused[:, closed:]))
    assert fused[:, :closed].abs().sum() > 0


@pytest.mark.parametrize("use", ["pullback only", "encoding only"])
def test_a_loss_on_one_output_alone_trains_the_table_the_same(ops, pytorch_path, use):
    encoding = HashGridEncoding(**SMALL, init_scale=0.1)
    x = _points(1000)
    grad_encoded = torch.randn(x.shape[0], encoding.output_dim, generator=torch.Generator().manual_seed(3))

    def table_grad():
        encoded, pullback = encoding.forward_with_pullback(x)
        loss = pullback(grad_encoded).square().sum() if use == "pullback only" else encoded.square().sum()
        return torch.autograd.grad(loss, encoding.table)[0]

    fused = table_grad()
    with pytorch_path:
        plain = table_grad()
    torch.testing.assert_close(fused, plain, rtol=1e-5, atol=1e-5 * plain.abs().max().item())
    assert plain.abs().sum() > 0


def test_the_thread_count_does_not_change_the_results(ops):
    encoding = HashGridEncoding(**SMALL, init_scale=0.1)
    weights = (torch.randn(encoding.output_dim, 8, generator=torch.Generator().manual_seed(4)) * 0.5).requires_grad_()
    x = _points(5000)
    before = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2):
            torch.set_num_threads(threads)
            results.append(_training_step(encoding, x, weights))
    finally:
        torch.set_num_threads(before)
    # the kernels' outputs: the encoding, the pull-back and the table's gradient (the weights' gradient is
    # torch's own matrix product, whose sum order follows the thread count on some CPUs)
    for one, two in zip(results[0][:3], results[1][:3]):
        assert torch.equal(one, two)


def test_points_that_need_gradients_take_the_pytorch_path(ops):
    encoding = HashGridEncoding(**SMALL, init_scale=0.1)
    x = _points(50)
    assert hash_kernel.usable(x, encoding.table, encoding.hashmap_size)
    assert not hash_kernel.usable(x.clone().requires_grad_(), encoding.table, encoding.hashmap_size)
    assert not hash_kernel.usable(x.double(), encoding.table.double(), encoding.hashmap_size)
    assert not hash_kernel.usable(x, encoding.table, 2**32)
    # and the gradient w.r.t. the points still comes (from the PyTorch path)
    points = x.clone().requires_grad_()
    (grad,) = torch.autograd.grad(encoding(points).sum(), points)
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0


def test_the_environment_switches_the_kernels_off(ops, monkeypatch):
    monkeypatch.setenv(hash_kernel.ENV_SWITCH, "0")
    assert hash_kernel.load_kernels() is None
    assert not hash_kernel.usable(_points(5), HashGridEncoding(**SMALL).table, 2**12)


def test_a_failed_build_warns_once_and_falls_back(monkeypatch):
    from torch.utils import cpp_extension

    def no_compiler(*args, **kwargs):
        raise RuntimeError("Error building extension 'va_hash_grid': c++: not found")

    monkeypatch.delenv(hash_kernel.ENV_SWITCH, raising=False)
    monkeypatch.setattr(hash_kernel, "_state", {})
    monkeypatch.setattr(cpp_extension, "load", no_compiler)
    with pytest.warns(RuntimeWarning, match="could not be built .*c\\+\\+: not found"):
        assert hash_kernel.load_kernels() is None
    assert hash_kernel.load_kernels() is None  # decided once
    encoding = HashGridEncoding(**SMALL, init_scale=1.0)
    assert torch.isfinite(encoding(_points(20))).all()


def test_nan_points_stay_in_their_own_rows(ops, pytorch_path):
    encoding = HashGridEncoding(**SMALL, init_scale=1.0)
    x = _points(100)
    x[7] = float("nan")
    fused = encoding(x)
    with pytorch_path:
        plain = encoding(x)
    assert torch.equal(fused.isnan(), plain.isnan())
    assert torch.isfinite(fused[torch.arange(x.shape[0]) != 7]).all()


def test_malformed_inputs_are_one_line_errors(ops):
    encoding = HashGridEncoding(**SMALL)
    levels = encoding.levels()
    args = hash_kernel._level_args(levels)
    with pytest.raises(RuntimeError, match="float32"):
        ops.encode(torch.rand(4, 3, dtype=torch.float64), encoding.table.detach(), *args)
    with pytest.raises(RuntimeError, match=r"contiguous \[n, 3\]"):
        ops.encode(torch.rand(4, 2), encoding.table.detach(), *args)
    with pytest.raises(RuntimeError, match="must be a contiguous float32"):
        ops.pullback(torch.rand(4, 3), encoding.table.detach(), torch.rand(4, 3), *args)


def test_double_backward_through_the_kernels_is_refused(ops):
    """The kernels give first-order gradients; a second backward through them raises instead of
    returning wrong values (points that need gradients, as an autograd eikonal does, never reach them)."""
    encoding = HashGridEncoding(**SMALL, init_scale=0.1)
    (grad,) = torch.autograd.grad(encoding(_points(50)).square().sum(), encoding.table, create_graph=True)
    with pytest.raises(RuntimeError):
        torch.autograd.grad(grad.sum(), encoding.table)


def test_flush_denormals_reaches_every_thread_of_the_pool_and_switches_back(ops):
    tiny = torch.full((1 << 20,), 1e-39)  # a denormal float32; a million of them split across the threads
    previous = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert bool((tiny * 1.0 == tiny).all())  # IEEE: denormals survive arithmetic
        assert hash_kernel.flush_denormals(True) is True
        assert int(torch.count_nonzero(tiny * 1.0)) == 0  # every chunk, on either thread, reads them as zero
        assert float(torch.tensor(1e-30) * torch.tensor(1e-10)) == 0.0  # and results below 1e-38 flush
        assert float(torch.tensor(1e-20) * torch.tensor(1e-10)) == pytest.approx(1e-30)  # normal values do not
    finally:
        hash_kernel.flush_denormals(False)
        torch.set_num_threads(previous)
    assert bool((tiny * 1.0 == tiny).all())


def test_denormals_flushed_holds_for_the_block_only(ops):
    tiny = torch.full((1 << 16,), 1e-39)
    with hash_kernel.denormals_flushed():
        assert int(torch.count_nonzero(tiny * 1.0)) == 0
    assert bool((tiny * 1.0 == tiny).all())  # off after the block: scipy and the rest see IEEE floats
    with hash_kernel.denormals_flushed(False):
        assert bool((tiny * 1.0 == tiny).all())


def test_denormals_flushed_blocks_nest(ops):
    """An inner block's end leaves the flushing on for the rest of the outer block (a render inside a
    training step's callbacks must not switch the step's flushing off)."""
    tiny = torch.full((1 << 16,), 1e-39)
    with hash_kernel.denormals_flushed():
        with hash_kernel.denormals_flushed():
            assert int(torch.count_nonzero(tiny * 1.0)) == 0
        assert int(torch.count_nonzero(tiny * 1.0)) == 0
    assert bool((tiny * 1.0 == tiny).all())


def test_a_field_render_flushes_denormals_on_the_cpu(ops, monkeypatch):
    """render_view (held-out views, turntables, the inconsistency maps) renders with denormals flushed:
    the field far from the surface underflows, and the slow path doubled the time of held-out renders."""
    from va_plugin.data.rigs import orbit_cameras
    from va_plugin.export.render import render_view

    seen = []

    class Model(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.weight = torch.nn.Parameter(torch.zeros(1))

        def render_rays(self, rays, keys):
            seen.append(float(torch.tensor(1e-30) * torch.tensor(1e-10)))
            return {"rgb": torch.zeros(len(rays.origins), 3)}

    image = render_view(Model(), orbit_cameras([0.0], 30.0, resolution=8), 0)
    assert image.shape == (8, 8, 3) and seen == [0.0]
    assert float(torch.tensor(1e-30) * torch.tensor(1e-10)) > 0.0  # off again afterwards
