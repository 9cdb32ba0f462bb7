"""svr.inference.calibration and svr.nmr.cones: the silhouette cone's field against hand-computed pixel distances and
projections, the mirror look, the settings' checks, and predict_sdf applying a checkpoint's
calibration (the search for a calibration: tests/svr/evaluation/test_calibration_search.py)."""
from __future__ import annotations

import math

import pytest
import torch

import renderer
from svr.inference.calibration import Calibration
from sdfcommon.numerics.hull import signed_pixel_distance
from svr.nmr.cones import silhouette_cone_sdf
from svr.inference.prediction import LoadedModel, predict_sdf

from tests.svr.models.test_models import tiny_net


def disc(size: int = 64, radius: float = 10.0) -> torch.Tensor:
    """(size, size) alpha: 1 within ``radius`` pixels of the image centre, else 0."""
    rc = torch.arange(size, dtype=torch.float32) - (size - 1) / 2
    return ((rc[:, None] ** 2 + rc[None, :] ** 2).sqrt() <= radius).float()


def test_cone_field_sign_and_scale_follow_the_projection():
    """The field is positive exactly where a sample projects outside the silhouette (away from the
    edge), and outside equals the pixel distance times the pixel's size at the sample's depth (deep
    inside, the pixel grid's distances are coarser: only their sign is checked)."""
    n, hs, view, radius = 24, 0.6, 3, 10.0
    field = silhouette_cone_sdf(disc(radius=radius)[None], torch.tensor([view]), n, hs)[0]
    axis = torch.linspace(-hs, hs, n)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    cams = renderer.Cameras.nmr([view])
    pix, depth = cams.project(points)
    from_centre = (pix[0] - 31.5).norm(dim=-1)
    expected_px = from_centre - radius  # distance to the disc's edge (pixels), positive outside
    f = field.reshape(-1)
    clear = (expected_px.abs() > 1.5) & (pix[0].min(-1).values > 0) & (pix[0].max(-1).values < 63)
    assert int(clear.sum()) > 1000
    assert bool(((f > 0) == (expected_px > 0))[clear].all())
    assert float(cams.fov_deg[0]) == pytest.approx(30.0)  # the NMR renders' field of view
    scale = depth[0] * 2 * math.tan(math.radians(30.0) / 2) / 64
    # the edge is the pixel grid's staircase of the disc: within a pixel of the round one
    outside = clear & (expected_px > 0)
    assert int(outside.sum()) > 1000
    assert bool(((f - expected_px * scale).abs() <= 1.0 * scale)[outside].all())


def test_mirror_carves_what_the_mirror_image_sees_outside():
    n, hs, view = 20, 0.6, 2  # an oblique view: a point and its mirror image project apart
    alpha = torch.zeros(1, 64, 64)
    alpha[0, :, :32] = 1.0  # the left half of the image is silhouette
    one = silhouette_cone_sdf(alpha, torch.tensor([view]), n, hs)[0]
    both = silhouette_cone_sdf(alpha, torch.tensor([view]), n, hs, mirror_axis=0)[0]
    assert bool((both >= one).all())
    flipped = torch.flip(one, dims=[0])  # x -> -x in the renderer.SDFGrid layout
    assert torch.allclose(both, torch.maximum(one, flipped), atol=1e-5)
    assert bool(((one < 0) & (both > 0)).any())  # some inside samples are carved by their mirror image


CONE_VIEWS = {
    "nmr": torch.tensor([3, 7, 3, 20, 7]),
    "fractional": torch.tensor([3.0, 7.5, 3.0, 20.25, 7.0]),
    "elevations": torch.tensor([[3.0, 30.0], [7.5, 12.0], [3.0, 30.0], [-4.2, 47.0], [3.0, 47.0]]),
}


@pytest.mark.parametrize("kind", sorted(CONE_VIEWS))
@pytest.mark.parametrize("mirror_axis", [None, 0])
def test_cone_of_a_mixed_batch_is_each_image_projected_by_its_own_camera(mirror_axis, kind):
    """The per-view lookup (computed once per view) puts every image's field in its own row: a batch
    of repeated and different views equals the fields projected through each image's camera, also
    for fractional views and (view, elevation) rows (cameras off NMR's 24)."""
    n, hs, size = 12, 0.6, 32
    gen = torch.Generator().manual_seed(3)
    alpha = (torch.rand(5, size, size, generator=gen) > 0.4).float()
    views = CONE_VIEWS[kind]
    field = silhouette_cone_sdf(alpha, views, n, hs, mirror_axis=mirror_axis)
    dist = signed_pixel_distance(alpha)[:, None]
    axis = torch.linspace(-hs, hs, n)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    if views.ndim == 2:
        cams = renderer.Cameras.nmr(views[:, 0], image_size=size, elevation_deg=views[:, 1])
    else:
        cams = renderer.Cameras.nmr(views, image_size=size)
    per_depth = (2.0 * torch.tan(torch.deg2rad(cams.fov_deg) / 2.0) / size)[:, None]

    def expected(pts):
        pix, depth = cams.project(pts)
        grid = ((pix + 0.5) * (2.0 / size) - 1.0).unsqueeze(1)
        d = torch.nn.functional.grid_sample(dist, grid, mode="bilinear", padding_mode="border", align_corners=False)
        return d[:, 0, 0] * depth * per_depth

    want = expected(points)
    if mirror_axis is not None:
        flip = torch.ones(3)
        flip[mirror_axis] = -1.0
        want = torch.maximum(want, expected(points * flip))
    assert torch.equal(field, want.reshape(5, n, n, n))
    with pytest.raises(ValueError, match="views has 4 entries for 5 images"):
        silhouette_cone_sdf(alpha, views[:4], n, hs)


def test_calibration_settings_are_checked():
    with pytest.raises(ValueError, match="carve must be one of"):
        Calibration(carve="hull")
    with pytest.raises(ValueError, match="needs mirror_axis"):
        Calibration(carve="view+mirror")
    with pytest.raises(ValueError, match="level must be a finite"):
        Calibration(level=float("nan"))
    with pytest.raises(ValueError, match="calibration: unknown keys"):
        Calibration.from_dict({"carve": "view", "shrink": 1})
    with pytest.raises(ValueError, match="carve_level must be a finite"):
        Calibration(carve="view", carve_level=float("inf"))
    cal = Calibration(carve="view+mirror", mirror_axis=0, level=0.01, carve_level=-0.005)
    assert Calibration.from_dict(cal.to_dict()) == cal
    assert Calibration().is_identity and not cal.is_identity
    # a record from before carve_level existed carved with the level added to both fields
    old = Calibration.from_dict({"carve": "view", "mirror_axis": None, "level": 0.01, "threshold": 0.5})
    assert old.carve_level == 0.01


def test_level_moves_the_network_surface_and_carve_level_the_cone():
    sdf = torch.tensor([-0.10, -0.02, 0.03, -0.30])
    cone = torch.tensor([-0.05, -0.05, -0.05, 0.01])
    out = Calibration(carve="view", level=0.04).apply(sdf, cone)
    # the level lifts the network's field only: the cone still reads -0.05 where it is the larger
    assert torch.allclose(out, torch.tensor([-0.05, 0.02, 0.07, 0.01]))
    wider = Calibration(carve="view", level=0.04, carve_level=-0.02).apply(sdf, cone)
    assert torch.allclose(wider, torch.tensor([-0.06, 0.02, 0.07, -0.01]))
    legacy = Calibration(carve="view", level=0.04, carve_level=0.04).apply(sdf, cone)
    assert torch.allclose(legacy, torch.maximum(sdf, cone) + 0.04)
    assert torch.equal(Calibration(level=0.04).apply(sdf, None), sdf + 0.04)


def test_predict_sdf_applies_the_calibration():
    torch.manual_seed(0)
    net = tiny_net()
    images = torch.rand(2, 4, 64, 64)
    raw = predict_sdf(LoadedModel(net), images, clip=False)
    shifted = predict_sdf(LoadedModel(net, calibration=Calibration(level=0.05)), images, clip=False)
    assert torch.allclose(shifted.coarse, raw.coarse + 0.05) and torch.allclose(shifted.refined, raw.refined + 0.05)
    off = predict_sdf(LoadedModel(net, calibration=Calibration(level=0.05)), images, clip=False, calibrated=False)
    assert torch.equal(off.refined, raw.refined)
    alpha_empty = images.clone()
    alpha_empty[:, 3] = 0.0  # nothing is silhouette: carving leaves no inside sample
    carved = predict_sdf(LoadedModel(net, calibration=Calibration(carve="view")), alpha_empty, clip=False,
                         views=[0, 5])
    assert bool((carved.refined > 0).all())
    uncarved = predict_sdf(LoadedModel(net, calibration=Calibration(carve="view")), alpha_empty, clip=False)
    # without views nothing can be carved
    assert torch.equal(uncarved.refined, predict_sdf(LoadedModel(net), alpha_empty, clip=False).refined)
