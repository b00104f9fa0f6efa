"""A check shared by the per-view adaptations of neus (camera refinement, deformation grids)."""

import torch


def assert_one_step_trains_unfrozen_views(trainer, loss_key: str, parameter) -> None:
    """One batch's loss holds ``loss_key``, and its backward gives ``parameter [V, ...]`` finite gradients
    that are zero for the frozen view 0 and not for the others."""
    model = trainer.model
    rays, batch = trainer.pipeline.datamanager.next_train(0)
    loss = model.get_loss_dict(model.get_outputs(rays), batch)
    assert loss_key in loss
    sum(loss.values()).backward()
    grad = parameter.grad
    assert torch.isfinite(grad).all() and grad[0].abs().sum() == 0 and grad[1:].abs().sum() > 0
