import torch

from va_plugin.model_components.samplers import sample_pdf, uniform_edges


def test_uniform_edges_without_jitter_are_stratum_centres():
    t = uniform_edges(torch.tensor([[1.0]]), torch.tensor([[3.0]]), 4, jitter=False)
    assert torch.allclose(t, torch.tensor([[1.25, 1.75, 2.25, 2.75]]))


def test_uniform_edges_jitter_stays_in_strata():
    g = torch.Generator().manual_seed(0)
    t = uniform_edges(torch.zeros(100, 1), torch.ones(100, 1), 4, jitter=True, generator=g)
    strata = torch.floor(t * 4)
    assert torch.equal(strata, torch.arange(4.0).expand(100, 4))


def test_sample_pdf_concentrates_in_heavy_bin():
    bins = torch.tensor([[0.0, 1.0, 2.0, 3.0]])
    weights = torch.tensor([[0.0, 1.0, 0.0]])
    t = sample_pdf(bins, weights, 16, jitter=False)
    inside = ((t >= 1.0) & (t <= 2.0)).float().mean()
    assert inside > 0.95
    assert (t >= 0).all() and (t <= 3).all()


def test_sample_pdf_all_zero_weights_is_uniform():
    bins = torch.linspace(0, 1, 5)[None]
    t = sample_pdf(bins, torch.zeros(1, 4), 8, jitter=False)
    assert torch.allclose(t, torch.linspace(1 / 16, 15 / 16, 8)[None], atol=1e-4)
