"""Issue 43, points 2 and 4: the input camera estimated from a photo, and the outputs a person can
use (the camera in JSON, the mesh in the camera's frame, a preview from that camera and three other
sides), on a tiny model=pixel checkpoint made here."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from hydra.utils import instantiate
from omegaconf import OmegaConf
from PIL import Image

import renderer
from sdfcommon.tooling.commands import compose
from svr.infer import main
from sdfcommon.tooling.settings import build_settings
from svr.inference.input_camera import (InputCamera, check_elevation, mesh_in_camera_frame, view_between,
                                        view_of_azimuth, weigh_votes)
from svr.inference.prediction import load_model
from svr.inference.reconstruction import infer_files
from svr.models.checkpoint_layout import CHECKPOINT_KEY

from ...entry_points import run_entry
from .test_documented_examples import TINY_PIXEL


def pixel_checkpoint(folder: Path, *extra: str) -> Path:
    """An untrained tiny model=pixel network (with its camera head unless ``extra`` drops it)."""
    config = OmegaConf.to_container(compose("train", [*TINY_PIXEL, *extra]).model, resolve=True)
    torch.manual_seed(0)
    net = instantiate(config)
    path = folder / "pixel.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in net.state_dict().items()},
                CHECKPOINT_KEY: {"stage": "joint", "model_config": config}}, path)
    return path


def compose_infer_settings(overrides: list[str]):
    return build_settings(compose("infer", ["ckpt_path=x.ckpt", "images=a.png", *overrides]))


def photo_jpeg(path: Path, size: tuple[int, int] = (160, 120), centre=(100, 50), radius: float = 22) -> Path:
    """A JPEG with no alpha: a red box and a grey disc, off-centre, on a plain white background."""
    w, h = size
    yy, xx = np.mgrid[:h, :w]
    rgb = np.full((h, w, 3), 255, np.uint8)
    rgb[((yy - centre[1]) ** 2 + (xx - centre[0]) ** 2) < radius ** 2] = (110, 110, 110)
    rgb[centre[1] - 6:centre[1] + 6, centre[0] - radius - 10:centre[0] - radius + 2] = (200, 30, 30)
    Image.fromarray(rgb, "RGB").save(path, quality=92)
    return path


def test_the_view_is_read_between_nmr_views_and_weighed_by_votes():
    probs = torch.zeros(4, 24, dtype=torch.float64)
    probs[0, 3] = 1.0                         # one view: exactly it
    probs[1, [3, 4]] = 0.5                    # halfway
    probs[2, [23, 0]] = torch.tensor([0.25, 0.75], dtype=torch.float64)  # across the wrap: a quarter back from 0
    probs[3, [5, 6, 12]] = torch.tensor([0.2, 0.4, 0.4], dtype=torch.float64)  # a tie: the lower view; 12 too far
    assert view_between(probs).tolist() == pytest.approx([3.0, 3.5, 23.75, 6 - 1 / 3])
    assert view_between(probs, span=0).tolist() == [3.0, 3.0, 0.0, 6.0]
    head = torch.full((1, 24), 0.01, dtype=torch.float64)
    head[0, 2], head[0, 14] = 0.4, 0.38       # the head's front and back, nearly tied
    votes = torch.zeros(1, 24, dtype=torch.float64)
    votes[0, 14] = 1.0                        # every neighbouring silhouette was seen from view 14
    weighed = weigh_votes(head, votes)
    assert weighed.sum().item() == pytest.approx(1.0) and int(weighed.argmax()) == 14
    # No votes (a bank without views): the head's probabilities, unchanged.
    assert weigh_votes(head, None) is head and int(weigh_votes(head, torch.full((1, 24), 1 / 24)).argmax()) == 2


def test_azimuths_and_nmr_views():
    assert view_of_azimuth(0) == 0.0 and view_of_azimuth(-90) == 6.0 and view_of_azimuth(270) == 6.0
    assert view_of_azimuth(15) == 23.0 and InputCamera(view=6).azimuth_deg == 270.0
    with pytest.raises(ValueError, match="azimuth must be a finite number"):
        view_of_azimuth(float("inf"))
    assert check_elevation(None) is None and check_elevation("12.5") == 12.5
    for bad in (90, -95, "high", float("nan")):
        with pytest.raises(ValueError, match=r"elevation must be a number of degrees in \(-90, 90\)"):
            check_elevation(bad)
    with pytest.raises(ValueError, match="elevation must be"):
        compose_infer_settings(["elevation=95"])


@pytest.mark.parametrize("view, elevation", [(0.0, 30.0), (5.0, 30.0), (13.5, 30.0), (7.25, 12.0), (20.0, 48.0)])
def test_the_camera_frame_is_the_renders_x_right_y_up_z_to_the_eye(view, elevation):
    """A point on the ray through pixel (row r, column c) of the renderer's NMR camera lands, in the
    camera's frame, at x / -z and y / -z of that pixel's place on the image plane (x to the right,
    y to the top); the eye is the origin and the world origin is 2.732 in front of it (also at
    elevations other than NMR's)."""
    cams = renderer.Cameras.nmr([view], image_size=8, dtype=torch.float64, elevation_deg=[elevation])
    origins, directions = cams.rays()
    camera = InputCamera(view=view, elevation_deg=elevation)
    assert camera.row == (view, elevation) and camera.record()["elevation_deg"] == elevation
    m = camera.world_to_camera()
    assert np.allclose(m @ np.array([0, 0, 0, 1.0]), [0, 0, -2.732, 1], atol=1e-9)
    assert np.linalg.det(m[:3, :3]) == pytest.approx(-1.0)  # NMR's camera is left-handed
    half = math.tan(math.radians(15.0))
    for r, c in ((0, 0), (2, 6), (7, 3)):
        p = (origins.reshape(-1, 3)[0] + 1.7 * directions.reshape(8, 8, 3)[r, c]).numpy()
        x, y, z, _ = m @ np.append(p, 1.0)
        assert z < 0
        assert x / -z == pytest.approx((2 * (c + 0.5) / 8 - 1) * half, abs=1e-9)
        assert y / -z == pytest.approx((1 - 2 * (r + 0.5) / 8) * half, abs=1e-9)


def test_the_camera_frame_mesh_keeps_its_normals_outward():
    box = trimesh.creation.box(extents=(0.2, 0.4, 0.6))
    moved = mesh_in_camera_frame(box, InputCamera(view=3))
    assert moved.is_watertight and moved.volume == pytest.approx(box.volume, rel=1e-9)  # positive: outward
    assert np.allclose(moved.centroid, InputCamera(view=3).world_to_camera()[:3, 3], atol=1e-9)


def test_a_jpeg_with_no_mask_and_no_camera_gives_every_output(tmp_path, monkeypatch, capsys):
    """``svr.infer`` on an RGB photo (plain background, off-centre, not 64x64), given no camera: the
    background is removed, the camera estimated by the head, the photo framed, and the files of
    point 4 written: the SDF, the meshes in the canonical frame and in the camera's, the camera in
    JSON and a preview of the input beside renders from the camera and three other sides."""
    ckpt = pixel_checkpoint(tmp_path)
    photo = photo_jpeg(tmp_path / "mug.jpg")
    out = tmp_path / "out"
    run_entry(main, [f"ckpt_path={ckpt}", f"images={photo}", f"output_dir={out}", "device=cpu", "progress=false",
                     "render_size=32"], monkeypatch)
    printed = capsys.readouterr().out
    assert "camera estimated: NMR view" in printed
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith(".") and p.suffix != ".log")
    assert names == ["mug.obj", "mug.ply", "mug_camera.json", "mug_camera_frame.ply", "mug_sdf.npz", "mug_views.png"]
    camera = json.loads((out / "mug_camera.json").read_text())
    assert camera["source"] == "estimated" and 0 <= camera["nmr_view"] < 24 and 0 < camera["probability"] <= 1
    assert camera["azimuth_deg"] == pytest.approx((-15 * camera["nmr_view"]) % 360)
    assert camera["elevation_deg"] == 30.0 and len(camera["world_to_camera"]) == 4
    transform = camera["photo_to_input"]
    assert transform["photo_size"] == [160, 120] and transform["framed_size"] == 64
    # The framing put the object's box centre (x 95, y 50 in the photo: the bar reaches to x 68,
    # the disc to 122) where the head's framing says, in input pixels.
    for axis, at in (("x", 95.0), ("y", 50.0)):
        framed = transform["scale"] * at + transform[f"offset_{axis}"]
        assert framed == pytest.approx(64 * camera["framing"][f"centre_{axis}"], abs=1.0)
    canonical = trimesh.load(out / "mug.ply", process=False)
    in_camera = trimesh.load(out / "mug_camera_frame.ply", process=False)
    m = np.array(camera["world_to_camera"])
    assert np.allclose(in_camera.vertices, canonical.vertices @ m[:3, :3].T + m[:3, 3], atol=1e-5)
    preview = np.asarray(Image.open(out / "mug_views.png"))
    assert preview.shape[1] == 6 * 32 + 5 * 4  # input RGB, its alpha, then the camera's view and 3 more


def test_the_estimated_or_given_elevation_reaches_the_json_and_the_camera_frame(tmp_path, monkeypatch):
    """A head with the elevation output (untrained: 30 degrees) writes its estimate; elevation=
    replaces it, and the camera-frame mesh follows the camera at that elevation."""
    ckpt = pixel_checkpoint(tmp_path, "model.camera.elevation=true")
    photo = photo_jpeg(tmp_path / "mug.jpg")
    for name, extra, want in (("estimated", [], 30.0), ("given", ["elevation=12.5"], 12.5)):
        out = tmp_path / name
        run_entry(main, [f"ckpt_path={ckpt}", f"images={photo}", f"output_dir={out}", "device=cpu", "progress=false",
                         "render_size=16", *extra], monkeypatch)
        camera = json.loads((out / "mug_camera.json").read_text())
        assert camera["elevation_deg"] == pytest.approx(want, abs=1e-4)
        m = np.array(camera["world_to_camera"])
        expected = InputCamera(view=camera["nmr_view"], elevation_deg=want).world_to_camera()
        assert np.allclose(m, expected, atol=1e-6)


def test_a_camera_reading_checkpoint_without_a_head_needs_the_camera(tmp_path, monkeypatch, capsys):
    """Trained before the camera head existed: no camera given is one line naming input_view and
    azimuth; azimuth= gives it (and is written as given)."""
    ckpt = pixel_checkpoint(tmp_path, "model.camera=null")
    photo = photo_jpeg(tmp_path / "mug.jpg")
    with pytest.raises(ValueError, match="input_view: this checkpoint reads the input camera and has no camera head"):
        infer_files(load_model(ckpt, "cpu"), photo, tmp_path / "a", views=[])
    report = infer_files(load_model(ckpt, "cpu"), photo, tmp_path / "b", views=[], azimuth=-90.0,
                         formats=["camera", "ply"])
    assert not report.failed
    camera = json.loads((tmp_path / "b" / "mug_camera.json").read_text())
    assert camera["source"] == "given" and camera["nmr_view"] == 6.0 and "photo_to_input" not in camera
    with pytest.raises(ValueError, match="input_view or azimuth, not both"):
        infer_files(load_model(ckpt, "cpu"), photo, tmp_path / "c", input_view=1, azimuth=30.0)


def test_framing_refuses_an_object_cut_off_by_the_border_in_one_line(tmp_path, monkeypatch, capsys):
    ckpt = pixel_checkpoint(tmp_path)
    photo = photo_jpeg(tmp_path / "cut.jpg", centre=(140, 60), radius=22)  # runs off the right edge
    report = infer_files(load_model(ckpt, "cpu"), photo, tmp_path / "out", views=[])
    (failed,) = report.failed
    assert "cut.jpg" in failed.error and "touches the image border" in failed.error and "\n" not in failed.error
