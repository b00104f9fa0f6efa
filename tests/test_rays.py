import torch

from va_plugin.rays import RayBundle, RaySamples, near_far_from_sphere


def test_near_far_hand_computed():
    origins = torch.tensor([[0.0, 0.0, -3.0], [0.0, 2.0, -3.0], [0.0, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    near, far, hits = near_far_from_sphere(origins, dirs, radius=1.0)
    assert torch.allclose(near[:, 0], torch.tensor([2.0, 0.0, 0.0]), atol=1e-6) or bool(hits[1]) is False
    assert hits.tolist() == [True, False, True]
    assert float(near[0]) == 2.0 and float(far[0]) == 4.0
    assert float(far[1]) == float(near[1])  # a miss has an empty interval
    assert float(near[2]) == 0.0 and float(far[2]) == 1.0  # inside the sphere: start at the origin


def test_tangent_and_zero_direction_are_finite():
    origins = torch.tensor([[0.0, 1.0, -3.0], [0.0, 0.0, -3.0]])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    near, far, hits = near_far_from_sphere(origins, dirs, 1.0)
    assert torch.isfinite(near).all() and torch.isfinite(far).all()
    assert not bool(hits[1])


def test_samples_from_edges():
    bundle = RayBundle(torch.zeros(1, 3), torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([2]))
    samples = RaySamples.from_edges(bundle, torch.tensor([[1.0, 2.0, 4.0]]))
    assert torch.allclose(samples.t_mid, torch.tensor([[1.5, 3.0]]))
    assert torch.allclose(samples.deltas, torch.tensor([[1.0, 2.0]]))
    assert torch.allclose(samples.positions[0, :, 0], torch.tensor([1.5, 3.0]))
    assert samples.camera_indices.tolist() == [2]
