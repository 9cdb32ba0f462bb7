"""svr.training.lr_schedules: the warm-up + cosine learning-rate curve, its resumption and bad arguments."""
from __future__ import annotations

import pytest
import torch

from svr.training.lr_schedules import warmup_cosine


def _lrs(sched, opt, steps):
    out = []
    for _ in range(steps):
        out.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    return out


def test_warmup_then_cosine_to_the_final_fraction():
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    sched = warmup_cosine(opt, total_steps=110, warmup_fraction=10 / 110, final_fraction=0.1)
    lrs = _lrs(sched, opt, 130)
    assert lrs[0] == pytest.approx(1 / 11)                      # starts small
    assert all(a < b for a, b in zip(lrs[:10], lrs[1:11]))      # rises during the warm-up
    assert lrs[10] == pytest.approx(1.0)                        # the full rate after it
    assert lrs[60] == pytest.approx(0.1 + 0.9 * 0.5)            # half way down the cosine
    assert lrs[110] == pytest.approx(0.1) and lrs[129] == pytest.approx(0.1)  # held at the end


def test_a_resumed_schedule_continues_the_same_curve():
    p = torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.SGD([p], lr=0.5)
    sched = warmup_cosine(opt, total_steps=50, warmup_fraction=0.1)
    _lrs(sched, opt, 20)
    state, opt_state = sched.state_dict(), opt.state_dict()  # what a checkpoint keeps
    opt2 = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=0.5)
    sched2 = warmup_cosine(opt2, total_steps=50, warmup_fraction=0.1)
    opt2.load_state_dict(opt_state)
    sched2.load_state_dict(state)
    assert _lrs(sched2, opt2, 10) == pytest.approx(_lrs(sched, opt, 10))


def test_a_tiny_budget_still_builds():
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    lrs = _lrs(warmup_cosine(opt, total_steps=2, warmup_fraction=0.05), opt, 3)  # warm-up rounds to 0 steps
    assert lrs[0] == pytest.approx(1.0) and lrs[2] == pytest.approx(0.05)


def test_bad_arguments_name_the_argument():
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    with pytest.raises(ValueError, match="total_steps"):
        warmup_cosine(opt, total_steps=0)
    with pytest.raises(ValueError, match="warmup_fraction"):
        warmup_cosine(opt, total_steps=10, warmup_fraction=1.0)
    with pytest.raises(ValueError, match="final_fraction"):
        warmup_cosine(opt, total_steps=10, final_fraction=1.5)
