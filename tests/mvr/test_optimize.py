"""optimise_level: greedy view selection, stopping rules, reports."""
from __future__ import annotations

import pytest
import torch

from mvr import OptimSettings, ViewLosses, make_target, optimise_level
from mvr.reconstruct import RigSettings, default_scene
from renderer import SDFGrid, TraceSettings


@pytest.fixture(scope="module")
def problem():
    scene = default_scene()
    cams = RigSettings().cameras(16)
    views = make_target("sphere", extent=1.0, mesh_resolution=48).render(cams, scene)
    grid = SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.7, 8, -1.0, 1.0)

    def losses(settings: OptimSettings) -> ViewLosses:
        return ViewLosses(cams, views.images, views.masks, scene, TraceSettings(), "auto", settings)

    return grid, losses


def test_level_reduces_the_loss(problem):
    grid, losses = problem
    settings = OptimSettings(max_passes=2, hard_view_updates=6, easy_view_updates=2, lr=0.1)
    fitted, report = optimise_level(grid, losses(settings), progress=False)
    assert report.loss_end < 0.5 * report.loss_start
    assert report.passes == len(report.history) <= 2 and report.updates > 0
    assert torch.equal(grid.values, SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.7, 8).values)  # untouched
    assert not fitted.values.requires_grad
    # Greedy selection: each of the 26 views gets at least 1 and at most 6 updates per pass.
    for h in report.history:
        assert 26 <= h["updates"] <= 26 * 6


FEW = dict(hard_view_updates=1, easy_view_updates=1)


@pytest.mark.parametrize("settings, reason", [
    (OptimSettings(max_passes=5, min_passes=1, loss_tol=1.0, **FEW), "loss_tol"),
    (OptimSettings(max_passes=5, min_passes=1, step_tol=1e9, **FEW), "step_tol"),
    (OptimSettings(max_passes=5, min_passes=1, rel_tol=10.0, patience=1, **FEW), "plateau"),
    (OptimSettings(max_passes=5, max_seconds=1e-6, **FEW), "max_seconds"),
    (OptimSettings(max_passes=1, **FEW), "max_passes"),
])
def test_stopping_rules(problem, settings, reason):
    grid, losses = problem
    _, report = optimise_level(grid, losses(settings), progress=False)
    assert report.stop_reason == reason and report.passes == 1


def test_view_losses_bad_input(problem):
    grid, losses = problem
    good = losses(OptimSettings())
    with pytest.raises(ValueError, match="do not match"):
        ViewLosses(good.cameras, good.images[:3], good.masks[:3], good.scene, good.trace, "auto", good.settings)
    with pytest.raises(ValueError, match="one grid"):
        optimise_level(SDFGrid(grid.values.expand(2, -1, -1, -1).clone()), good, progress=False)
