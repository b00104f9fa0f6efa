"""The guard's finite-value check (min/max based) against the plain reference, isfinite(t).all()."""

import pytest
import torch

from va_plugin.engine.health import all_finite


@pytest.mark.parametrize("n", [1, 2, 17, 4099, 300_001])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_all_finite_matches_the_reference_wherever_the_bad_value_sits(n, value):
    generator = torch.Generator().manual_seed(n)
    for position in {0, n // 2, n - 1, int(torch.randint(0, n, (), generator=generator))}:
        t = torch.randn(n, generator=generator)
        assert all_finite([t]) is True
        t[position] = value
        assert all_finite([t]) == bool(torch.isfinite(t).all()) is False


def test_all_finite_skips_none_and_empty_and_reads_strided_views():
    t = torch.randn(100, 64)[:, ::3]
    assert all_finite([None, torch.empty(0), t, torch.full((3,), 3e38)])
    t[5, 2] = float("nan")
    assert not all_finite([torch.ones(2), t])
