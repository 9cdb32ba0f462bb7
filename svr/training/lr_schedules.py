"""Learning-rate schedules for the training stages (``stage.<name>.scheduler`` in the config)."""
from __future__ import annotations

import math

import torch


def warmup_cosine(optimizer: torch.optim.Optimizer, total_steps: int, warmup_fraction: float = 0.0,
                  final_fraction: float = 0.05) -> torch.optim.lr_scheduler.LambdaLR:
    """Linear warm-up from near zero to the optimiser's learning rate over the first
    ``warmup_fraction`` of ``total_steps``, then a cosine decay to ``final_fraction`` of it at
    ``total_steps`` (held there after). Fractions, so a changed step budget keeps the curve's shape.

    Stepped once per training step (the LightningModule's ``interval: step``). Its state (the step
    count) is saved in every checkpoint, so a resumed stage continues the same curve.

    Args:
        optimizer: the stage's optimiser. total_steps: the stage's step budget (>= 1).
        warmup_fraction: the share of the steps spent warming up, in [0, 1) (0 for none).
        final_fraction: the learning rate at the end, as a fraction of the initial one (in [0, 1]).
    """
    if isinstance(total_steps, bool) or not isinstance(total_steps, int) or total_steps < 1:
        raise ValueError(f"total_steps must be a positive int, got {total_steps!r}")
    if isinstance(warmup_fraction, bool) or not isinstance(warmup_fraction, (int, float)) \
            or not 0.0 <= warmup_fraction < 1.0:
        raise ValueError(f"warmup_fraction must be a number in [0, 1), got {warmup_fraction!r}")
    warmup_steps = int(round(warmup_fraction * total_steps))
    if not 0.0 <= float(final_fraction) <= 1.0:
        raise ValueError(f"final_fraction must lie in [0, 1], got {final_fraction!r}")
    final = float(final_fraction)

    def factor(step: int) -> float:
        if step < warmup_steps:
            return (step + 1) / (warmup_steps + 1)
        t = min(1.0, (step - warmup_steps) / max(1, total_steps - warmup_steps))
        return final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * t))

    return torch.optim.lr_scheduler.LambdaLR(optimizer, factor)


__all__ = ["warmup_cosine"]
