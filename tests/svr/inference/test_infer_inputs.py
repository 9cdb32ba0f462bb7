"""svr.infer with a user's own inputs (issue 40 items 9, 10, 14, 15): an image that fails (unreadable,
no surface) is reported and the others go on, exit status 2 at the end; what a folder held that was
not read is listed; a rerun into a folder with results is refused unless overwrite=true; glob
patterns; formats=[] and input_view outside [0, 24) refused; inverted masks of objects that touch
the border refused; meshes of fields with samples on the surface are cleaned and watertight.

The model is a stand-in network (``FieldNet``: the SDF of a sphere sized by the silhouette's area),
so these tests need no training run."""
from __future__ import annotations

import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

import svr.infer
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import build_settings
from svr.infer import main
from svr.inference.images import find_images, load_image
from svr.inference.prediction import LoadedModel, check_input_views, predict
from svr.inference.reconstruction import (check_formats, clean_mesh, infer_files, mesh_problem,
                                          reconstruct_images)
from svr.models.network import SVRPrediction

from ...entry_points import expect_usage_error, files_under, run_entry
from ..evaluation.test_evaluate import refused_before_any_folder


class FieldNet(torch.nn.Module):
    """Stands in for an SVRNet: the SDF of a sphere whose radius grows with the silhouette's area
    (2 * mean alpha - 0.05: none, so no surface, for a silhouette under 2.5% of the image);
    ``rounded``: values rounded to 0.01, so some samples lie exactly on the surface."""

    half_side = 0.6

    def __init__(self, n: int = 16, rounded: bool = False, needs_views: bool = False) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.zeros(()))  # gives the model a device
        self.encoder = SimpleNamespace(image_size=64)
        self.decoder = SimpleNamespace(grid_resolution=n)
        self.n, self.rounded, self.needs_views = n, rounded, needs_views

    def forward(self, images: torch.Tensor, refine: bool = True, views=None) -> SVRPrediction:
        axis = torch.linspace(-self.half_side, self.half_side, self.n)
        radius = 2 * images[:, 3].mean((1, 2)) - 0.05
        sdf = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).norm(dim=-1) - radius[:, None, None, None]
        if self.rounded:
            sdf = torch.round(sdf * 100) / 100
        return SVRPrediction(coarse=sdf, refined=sdf)


def disc_png(path: Path, radius: float = 16, centre=(32, 32), inverted: bool = False, mask: bool = False) -> Path:
    """A 64x64 grey disc on a transparent background as RGBA (or, ``mask``, as a grey-level mask:
    white = object); ``inverted``: the disc transparent (black), the background opaque."""
    yy, xx = np.mgrid[:64, :64]
    alpha = np.where(((yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < radius ** 2) != inverted, 255, 0).astype(np.uint8)
    if mask:
        Image.fromarray(alpha, "L").save(path)
    else:
        rgba = np.dstack([np.full((64, 64, 3), 128, np.uint8), alpha])
        Image.fromarray(rgba, "RGBA").save(path)
    return path


@pytest.fixture
def fake_model(monkeypatch) -> LoadedModel:
    """The stand-in network, also what the command loads for any ``ckpt_path``."""
    model = LoadedModel(FieldNet())
    monkeypatch.setattr(svr.infer, "load_model", lambda path, device: model)
    return model


def run_command(args: list[str], monkeypatch, capsys) -> tuple[int, str, str]:
    """Runs ``svr.infer.main`` with ``args``; returns (exit status, stdout, stderr)."""
    capsys.readouterr()
    code = 0
    try:
        run_entry(main, [*args, "ckpt_path=fake.ckpt", "device=cpu", "views=[]", "progress=false"], monkeypatch)
    except SystemExit as stop:
        code = stop.code
    out, err = capsys.readouterr()
    return code, out, err


def test_a_failed_image_is_reported_and_the_others_go_on(fake_model, tmp_path, monkeypatch, capsys):
    """Items 9 and 15: an unreadable image and one with no surface fail alone; the command lists
    them and what the folder held that it did not read, and exits with status 2."""
    photos = tmp_path / "photos"
    photos.mkdir()
    disc_png(photos / "good.png")
    disc_png(photos / "speck.png", radius=2)  # too small for a surface: the SDF is positive everywhere
    (photos / "broken.png").write_bytes(b"not an image")
    (photos / "notes.txt").write_text("x")
    (photos / "photo.webp").write_bytes(b"RIFF")
    (photos / "older").mkdir()
    (photos / ".DS_Store").write_bytes(b"")
    out = tmp_path / "out"
    # Not framed: framing would enlarge the speck to the training renders' size.
    code, printed, err = run_command([f"images={photos}", f"output_dir={out}", "frame=false"], monkeypatch, capsys)
    assert code == 2, err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and "Traceback" not in err, err
    assert errors[0].startswith("sdfdiff-infer: error: 2 of 3 image(s) failed")
    assert "broken.png" in errors[0] and "speck.png" in errors[0]
    assert f"failed: {photos / 'broken.png'}: cannot read the image" in printed
    assert f"failed: {photos / 'speck.png'}: no surface" in printed
    assert ("skipped 3 file(s) or folder(s) that are not PNG/JPEG images: "
            f"{photos / 'notes.txt'}, {photos / 'older'}, {photos / 'photo.webp'}") in printed
    assert f"1 of 3 image(s) done, 2 failed -> {out}" in printed
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".") and p.suffix != ".log") == [
        "good.obj", "good.ply", "good_sdf.npz", "good_views.png"]  # nothing for the failed ones
    assert trimesh.load(out / "good.ply", process=False).is_watertight

    # The Python API says the same in its report.
    report = infer_files(fake_model, photos, tmp_path / "api", views=[], formats=["npz", "ply"], frame=False)
    assert [r.image.name for r in report.done] == ["good.png"] and set(report.done[0].files) == {"npz", "ply"}
    assert [(r.image.name, r.files) for r in report.failed] == [("broken.png", {}), ("speck.png", {})]
    assert "no surface" in report.failed[1].error
    assert [p.name for p in report.skipped] == ["notes.txt", "older", "photo.webp"]


def test_a_rerun_into_a_folder_with_results_is_refused_unless_overwrite(fake_model, tmp_path, monkeypatch, capsys):
    """Item 15: the second run would replace the first's results and its .hydra record."""
    image = disc_png(tmp_path / "disc.png")
    out = tmp_path / "out"
    code, printed, err = run_command([f"images={image}", f"output_dir={out}"], monkeypatch, capsys)
    assert code == 0 and "1 of 1 image(s) done, 0 failed" in printed, err
    before = files_under(out)
    line = expect_usage_error(main, [f"images={image}", f"output_dir={out}", "ckpt_path=fake.ckpt", "device=cpu",
                                     "views=[]", "progress=false"], monkeypatch, capsys,
                              "sdfdiff-infer")
    assert f"output_dir: {out} already holds files (disc.obj, disc.ply, disc_sdf.npz, ...)" in line
    assert "overwrite=true" in line
    assert files_under(out) == before  # its results and its .hydra record as they were
    code, printed, err = run_command([f"images={image}", f"output_dir={out}", "overwrite=true", "formats=[npz]"],
                                     monkeypatch, capsys)
    assert code == 0 and "1 of 1 image(s) done" in printed, err
    # A folder of the user's other files is refused the same way (the images' own folder, say).
    line = expect_usage_error(main, [f"images={image}", f"output_dir={tmp_path}", "ckpt_path=fake.ckpt", "device=cpu",
                                     "views=[]", "progress=false"], monkeypatch, capsys)
    assert "already holds files" in line


def test_glob_patterns_are_expanded(fake_model, tmp_path, monkeypatch, capsys):
    """Item 15: ``images='dir/*.png'`` (a pattern the shell passed on) was "image not found"."""
    for name in ("a.png", "b.png"):
        disc_png(tmp_path / name)
    (tmp_path / "c.webp").write_bytes(b"RIFF")
    disc_png(tmp_path / "a_mask.png", mask=True)
    found = find_images(str(tmp_path / "*.png"))
    assert [p.name for p in found.images] == ["a.png", "b.png"] and found.skipped == ()
    found = find_images([tmp_path / "?.*"])
    assert [p.name for p in found.images] == ["a.png", "b.png"] and [p.name for p in found.skipped] == ["c.webp"]
    with pytest.raises(FileNotFoundError, match=r"no file matches the pattern .*\*\.gif"):
        find_images(str(tmp_path / "*.gif"))
    with pytest.raises(ValueError, match=r"no PNG/JPEG image in the pattern .*\*\.webp"):
        find_images(str(tmp_path / "*.webp"))
    out = tmp_path / "out"
    code, printed, err = run_command([f"images={tmp_path}/*.png", f"output_dir={out}", "formats=[npz]"],
                                     monkeypatch, capsys)
    assert code == 0 and "2 of 2 image(s) done" in printed, err
    assert sorted(p.name for p in out.glob("*.npz")) == ["a_sdf.npz", "b_sdf.npz"]


def test_formats_must_name_something(tmp_path, monkeypatch, capsys):
    """Item 15: formats=[] ran, wrote nothing and printed "wrote "."""
    lines = refused_before_any_folder(main, ["ckpt_path=missing.ckpt", "images=missing.png", "formats=[]"],
                                      "sdfdiff-infer", tmp_path, monkeypatch, capsys)
    assert all("formats must be a non-empty list among" in line for line in lines), lines
    with pytest.raises(ValueError, match="formats"):
        check_formats([])


@pytest.mark.parametrize("value", ["24", "-1", "1e9", "nan"])
def test_input_view_outside_the_24_views_is_one_line(value, tmp_path, monkeypatch, capsys):
    """Item 14: input_view=24, -1 and 1e9 were accepted (views are 0..23, fractional between)."""
    lines = refused_before_any_folder(main, ["ckpt_path=missing.ckpt", "images=missing.png", f"input_view={value}"],
                                      "sdfdiff-infer", tmp_path, monkeypatch, capsys)
    assert all("input_view must be an NMR view index in [0, 24)" in line for line in lines), lines


def test_input_view_range_in_the_python_api(tmp_path):
    assert build_settings(compose("infer", ["ckpt_path=x.ckpt", "images=a.png", "input_view=23.5"])).input_view == 23.5
    model = LoadedModel(FieldNet(needs_views=True))
    images = load_image(disc_png(tmp_path / "disc.png"))[None]
    assert predict(model, images, views=23.5).values.shape == (1, 16, 16, 16)
    with pytest.raises(ValueError, match=r"views must be an NMR view index in \[0, 24\).*got 24$"):
        predict(model, images, views=24)
    with pytest.raises(ValueError, match=r"input_view must be .*got -1$"):
        infer_files(model, [tmp_path / "disc.png"], tmp_path / "out", input_view=-1)


def test_views_as_view_and_elevation_rows(tmp_path):
    """A camera off NMR's 24 (an extra training view, a photo's estimate): (view, elevation) rows."""
    model = LoadedModel(FieldNet(needs_views=True))
    images = load_image(disc_png(tmp_path / "disc.png"))[None]
    rows = torch.tensor([[3.5, 12.0]])
    assert torch.equal(check_input_views(rows, 1, True), rows)
    assert predict(model, images, views=rows).values.shape == (1, 16, 16, 16)
    with pytest.raises(ValueError, match=r"elevations must lie in \(-90, 90\)"):
        check_input_views(torch.tensor([[3.0, 95.0]]), 1, True)
    with pytest.raises(ValueError, match="one \\(view, elevation\\) row per image \\(2\\), got 1"):
        check_input_views(rows, 2, True)
    with pytest.raises(ValueError, match="got 24.5"):
        check_input_views(torch.tensor([[24.5, 30.0]]), 1, True)


def test_an_inverted_mask_is_refused_when_the_object_touches_the_border(tmp_path):
    """Item 10: only a silhouette covering the whole border was taken for an inverted one."""
    with pytest.raises(ValueError, match=r"edge.png: the silhouette covers \d+% of the image border.*inverted"):
        load_image(disc_png(tmp_path / "edge.png", centre=(60, 32), inverted=True))  # a disc cut by the bottom edge
    Image.new("RGB", (64, 64), "grey").save(tmp_path / "photo.png")
    mask = disc_png(tmp_path / "photo_mask.png", radius=20, centre=(32, 0), inverted=True, mask=True)
    with pytest.raises(ValueError, match="photo_mask.png: .*inverted"):
        load_image(tmp_path / "photo.png", mask)
    # The same objects the right way round, and one cropped tightly at two edges, are accepted.
    assert load_image(disc_png(tmp_path / "edge_ok.png", centre=(60, 32))).shape == (4, 64, 64)
    assert load_image(disc_png(tmp_path / "corner.png", radius=40, centre=(63, 63))).shape == (4, 64, 64)
    ok_mask = disc_png(tmp_path / "ok_mask.png", radius=20, centre=(32, 0), mask=True)
    assert load_image(tmp_path / "photo.png", ok_mask).shape == (4, 64, 64)


def test_samples_on_the_surface_still_give_a_watertight_mesh(tmp_path):
    """Item 9: a field with samples exactly at zero gave marching-cubes meshes with degenerate,
    duplicate and non-manifold faces (not watertight)."""
    images = torch.stack([load_image(disc_png(tmp_path / f"d{r}.png", radius=r)) for r in (12, 14, 16, 18)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no "not watertight" warning
        recs = reconstruct_images(LoadedModel(FieldNet(n=32, rounded=True)), images, views=[])
    assert all(r.watertight and r.problem is None and len(r.mesh.faces) for r in recs)
    assert all(len(r.mesh.faces) == len(r.mesh.unique_faces()) for r in recs)
    assert all(bool(r.mesh.nondegenerate_faces().all()) for r in recs)


def test_clean_mesh_merges_and_drops_what_is_not_surface():
    box = trimesh.creation.box()
    faces = np.vstack([box.faces, box.faces[:1], [[0, 0, 1]]])  # a duplicate face, a face without area
    vertices = np.vstack([box.vertices, box.vertices[:1]])  # a duplicate vertex, used by the last face
    faces[-1] = [0, len(vertices) - 1, 1]
    messy = trimesh.Trimesh(vertices, faces, process=False)
    assert not messy.is_watertight and "the mesh is not watertight: " in mesh_problem(messy)
    clean = clean_mesh(messy)
    assert clean.is_watertight and len(clean.faces) == 12 and len(clean.vertices) == 8
    assert mesh_problem(clean) is None and len(messy.faces) == 14  # the input is left as it was
    assert mesh_problem(trimesh.Trimesh()).startswith("no surface")
