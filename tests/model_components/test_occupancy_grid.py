import pytest
import torch

from va_plugin.cameras import Cameras
from va_plugin.errors import ConfigError
from va_plugin.model_components.occupancy_grid import OccupancyGrid, OccupancyGridConfig, scatter, transmittance_before


def _grid(**changes) -> OccupancyGrid:
    options = dict(resolution=16, warmup_steps=10, update_every=1)
    options.update(changes)
    return OccupancyGrid(OccupancyGridConfig(**options), bound=1.0)


def _ball(radius: float = 0.3, inside: float = 100.0):
    """A density of ``inside`` within ``radius`` of the origin and 0 elsewhere."""
    return lambda p: torch.where(p.norm(dim=-1) < radius, inside, 0.0)


def test_warmup_prunes_nothing():
    torch.manual_seed(0)
    grid = _grid()
    probe = torch.rand(2000, 3) * 1.8 - 0.9
    for step in range(10):
        grid.update(step, _ball())
        assert grid.occupied(probe).all()
    assert grid.occupied_fraction() == 1.0


def test_update_keeps_dense_cells_and_drops_empty_ones_after_warmup():
    torch.manual_seed(0)
    grid = _grid()
    for step in range(12):
        grid.update(step, _ball())
    assert grid.occupied(torch.tensor([[0.0, 0.0, 0.0], [0.1, -0.1, 0.05]])).all()
    assert not grid.occupied(torch.tensor([[0.8, 0.0, 0.0], [-0.5, 0.5, 0.0], [0.0, 0.0, -0.7]])).any()
    assert 0.0 < grid.occupied_fraction() < 0.1


def test_max_decay_forgets_a_cell_that_empties():
    torch.manual_seed(0)
    grid = _grid(decay=0.5)
    for step in range(12):
        grid.update(step, _ball())
    centre, elsewhere = torch.zeros(1, 3), torch.tensor([[0.5, 0.0, 0.0]])
    assert grid.occupied(centre).all() and not grid.occupied(elsewhere).any()
    moved = lambda p: _ball()(p - elsewhere)
    grid.update(12, moved)
    assert grid.occupied(centre).all() and grid.occupied(elsewhere).all()  # the max remembers the old ball
    for step in range(13, 22):
        grid.update(step, moved)
    assert not grid.occupied(centre).any() and grid.occupied(elsewhere).all()


def test_threshold_floor_keeps_a_faint_field_from_being_pruned_empty():
    torch.manual_seed(0)
    grid = _grid(warmup_steps=0, threshold=0.5)
    # an "untrained" field: faint everywhere (every cell far below the threshold), slightly denser at +x
    grid.update(0, lambda p: 0.01 * (2.0 + p[:, 0]))
    fraction = grid.occupied_fraction()
    assert 0.3 < fraction < 0.7
    assert grid.occupied(torch.tensor([[0.8, 0.0, 0.0]])).all()


def test_points_outside_the_grid_are_empty_and_state_is_checkpointed():
    grid = _grid()
    assert not grid.occupied(torch.tensor([[1.5, 0.0, 0.0], [0.0, -1.01, 0.0]])).any()
    assert grid.occupied(torch.tensor([[0.99, 0.0, 0.0]])).all()
    state = grid.state_dict()
    assert set(state) == {"values", "binary", "seen"}


def test_cells_outside_the_views_are_never_occupied_after_warmup():
    # one camera at z = -2 looking along +z with a narrow field of view (about +-0.4 at the origin)
    c2w = torch.tensor([[[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, -2.0]]])
    cameras = Cameras(c2w, 40.0, 40.0, 8.0, 8.0, 16, 16)
    grid = _grid(warmup_steps=1)
    grid.restrict_to_views(cameras, min_views=1)
    dense_everywhere = lambda p: torch.full(p.shape[:1], 100.0)
    grid.update(0, dense_everywhere)
    assert grid.occupied(torch.tensor([[0.8, 0.0, 0.0]])).all()  # warm-up: nothing pruned
    grid.update(1, dense_everywhere)
    assert grid.occupied(torch.tensor([[0.0, 0.0, 0.0], [0.2, -0.2, 0.5]])).all()
    assert not grid.occupied(torch.tensor([[0.8, 0.0, 0.0], [0.0, -0.7, 0.0]])).any()
    grid.restrict_to_views(cameras, min_views=2)  # more views than there are: nothing may be occupied
    grid.update(2, dense_everywhere)
    assert grid.occupied_fraction() == 0.0


def test_bad_config_is_a_config_error():
    with pytest.raises(ConfigError, match="decay"):
        _grid(decay=1.5)
    with pytest.raises(ConfigError, match="threshold"):
        _grid(threshold=-0.1)
    with pytest.raises(ConfigError, match="min_view_fraction"):
        _grid(min_view_fraction=2.0)
    with pytest.raises(ConfigError, match="resolution"):
        _grid(resolution=0)


def test_transmittance_hand_computed():
    alpha = torch.tensor([[0.5, 0.5, 1.0, 0.3]])
    expected = torch.tensor([[1.0, 0.5, 0.25, 0.0]])
    assert torch.allclose(transmittance_before(alpha), expected, atol=1e-6)


def test_scatter_inverts_masking_and_passes_gradients():
    keep = torch.tensor([[True, False, True], [False, False, False]])
    packed = torch.tensor([2.0, 3.0], requires_grad=True)
    dense = scatter(packed, keep)
    assert torch.equal(dense.detach(), torch.tensor([[2.0, 0.0, 3.0], [0.0, 0.0, 0.0]]))
    assert torch.equal(dense[keep].detach(), packed.detach())
    (dense * torch.arange(6.0).view(2, 3)).sum().backward()
    assert torch.equal(packed.grad, torch.tensor([0.0, 2.0]))
    empty = torch.zeros(0, 3, requires_grad=True)
    assert scatter(empty, torch.zeros(2, 4, dtype=torch.bool)).shape == (2, 4, 3)
