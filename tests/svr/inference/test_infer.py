"""svr.infer: a dataset image through the command line gives the evaluation's prediction (voxel IoU
1) as a watertight mesh; the in-memory API; RGB + mask and resizing; CPU/GPU checkpoints; errors."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

import renderer
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import PathSettings, build_settings
from svr.evaluation.protocol import evaluate
from svr.infer import main
from svr.inference.images import load_image
from svr.inference.prediction import LoadedModel, check_images, load_model, predict, predict_sdf, resolve_device
from svr.inference.reconstruction import infer_files, reconstruct_images
from svr.inference.settings import InferSettings
from svr.nmr.metrics import voxel_iou
from svr.nmr.voxels import voxelize_mesh_nmr

from ...entry_points import expect_usage_error, run_entry
from ..evaluation.test_evaluate import refused_before_any_folder, run_main, tiny_run  # noqa: F401  (the shared run)

ROOT = Path(__file__).resolve().parents[3]


def save_rgba(u8: np.ndarray, path) -> None:
    """(4, H, W) uint8 -> an RGBA PNG."""
    Image.fromarray(np.ascontiguousarray(u8.transpose(1, 2, 0)), "RGBA").save(path)


def test_dataset_image_gives_the_evaluations_prediction_as_a_watertight_mesh(tiny_run, tmp_path, capsys,
                                                                            monkeypatch):
    model = load_model(tiny_run.checkpoint, "cpu")
    dm = tiny_run.datamodule()
    res = evaluate(model, dm, "test", views=[5, 11], keep_voxels=True, progress=False)
    objects = dm.dataset("test")
    cat, view = 1, 11  # the mug, view 11
    obj = int(objects.offsets[cat])
    save_rgba(objects.images_uint8(obj, [view])[0], tmp_path / "mug_v11.png")
    save_rgba(objects.images_uint8(int(objects.offsets[0]), [5])[0], tmp_path / "chair_v5.png")

    out = tmp_path / "out"
    run_main(main, [f"ckpt_path={tiny_run.checkpoint}", f"images={tmp_path}", f"output_dir={out}", "device=cpu",
                    "views=[0,12]", "render_size=32"], tmp_path / "hydra", monkeypatch)
    printed = capsys.readouterr().out
    assert "2 image(s)" in printed
    for stem, c, v in (("mug_v11", cat, view), ("chair_v5", 0, 5)):
        for suffix in ("_sdf.npz", ".ply", ".obj", "_views.png"):
            assert (out / f"{stem}{suffix}").is_file(), f"{stem}{suffix} missing"
        expected = res.voxels[res.index_of(c, 0, v)]
        for ext in ("ply", "obj"):
            mesh = trimesh.load(out / f"{stem}.{ext}", force="mesh", process=False)
            assert mesh.is_watertight and len(mesh.faces) > 0
            vox = voxelize_mesh_nmr(mesh.vertices, mesh.faces)
            assert float(voxel_iou(vox, expected)[0]) == 1.0, f"{stem}.{ext}"
        with np.load(out / f"{stem}_sdf.npz") as z:
            values, lo, hi = z["values"], z["bbox_min"], z["bbox_max"]
            assert str(z["stage"]) == "refine"
        n = model.net.grid_resolution
        assert values.shape == (n, n, n) and values.dtype == np.float32
        assert np.allclose(lo, -model.half_side) and np.allclose(hi, model.half_side)
        direct = predict(model, objects.views(int(objects.offsets[c]), [v])).values[0]
        assert np.allclose(values, direct.numpy(), atol=1e-5)
        png = Image.open(out / f"{stem}_views.png")
        assert png.size[1] == 32 and png.size[0] > 4 * 32  # input, alpha, 2 renders
    # The two inputs give different predictions (the file was not mixed up with another).
    with np.load(out / "mug_v11_sdf.npz") as a, np.load(out / "chair_v5_sdf.npz") as b:
        assert not np.array_equal(a["values"], b["values"])


def test_in_memory_api(tiny_run):
    model = load_model(tiny_run.checkpoint, "cpu")
    images = tiny_run.datamodule().dataset("test").views(0, [0, 7, 13])
    grid = predict(model, images, batch_size=2)
    n = model.net.grid_resolution
    assert isinstance(grid, renderer.SDFGrid) and grid.values.shape == (3, n, n, n)
    assert torch.allclose(grid.values, predict(model, images).values, atol=1e-5)  # batching does not matter
    both = predict_sdf(model, images)
    assert both.refined is not None and torch.allclose(both.refined, grid.values, atol=1e-5)
    assert not torch.allclose(both.coarse, both.refined)  # the tiny run trained the refiner
    from_path = predict(load_model(tiny_run.checkpoint), images[:1]).values  # loaded onto the "auto" device
    tol = 1e-5 if from_path.device.type == "cpu" else 1e-3  # a GPU's convolutions may run in TF32
    assert torch.allclose(from_path.cpu(), grid.values[:1], atol=tol)
    bare = predict(LoadedModel(model.net), images[:1]).values  # a network in memory, treated as fully trained
    assert torch.allclose(bare, grid.values[:1], atol=1e-5)
    for not_loaded in (tiny_run.checkpoint, str(tiny_run.checkpoint), model.net):  # only commands load paths
        with pytest.raises(TypeError, match="model must be a LoadedModel"):
            predict(not_loaded, images[:1])
        with pytest.raises(TypeError, match="model must be a LoadedModel"):
            reconstruct_images(not_loaded, images[:1], views=[])
    recs = reconstruct_images(model, images[:2], views=[0], render_size=24)
    assert all(r.watertight for r in recs)
    assert recs[0].renders.shape == (1, 24, 24, 3)
    with pytest.raises(ValueError, match="images"):
        check_images(torch.rand(2, 3, 64, 64))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        predict(model, images * 255)


def test_rgb_plus_mask_equals_rgba_and_other_sizes_are_resized(tiny_run, tmp_path):
    u8 = tiny_run.datamodule().dataset("test").images_uint8(0, [3])[0]
    save_rgba(u8, tmp_path / "a.png")
    Image.fromarray(np.ascontiguousarray(u8[:3].transpose(1, 2, 0)), "RGB").save(tmp_path / "b.png")
    Image.fromarray(u8[3]).save(tmp_path / "b_mask.png")
    rgba = load_image(tmp_path / "a.png")
    assert torch.equal(rgba, load_image(tmp_path / "b.png", tmp_path / "b_mask.png"))
    # Without the mask, the white background of the dataset's RGB is removed instead: the same
    # silhouette but for edge pixels.
    Image.fromarray(np.ascontiguousarray((rgba[:3] * 255).round().byte().numpy().transpose(1, 2, 0)), "RGB").save(
        tmp_path / "plain.png")
    removed = load_image(tmp_path / "plain.png")
    inter = ((removed[3] >= 0.5) & (rgba[3] >= 0.5)).sum()
    assert inter / ((removed[3] >= 0.5) | (rgba[3] >= 0.5)).sum() > 0.9
    big = Image.fromarray(np.ascontiguousarray(u8.transpose(1, 2, 0)), "RGBA").resize((128, 96))
    big.save(tmp_path / "big.png")
    with pytest.warns(UserWarning, match="resized to 64x64"):
        x = load_image(tmp_path / "big.png")
    assert x.shape == (4, 64, 64) and 0 <= float(x.min()) and float(x.max()) <= 1
    # A folder: the mask is found beside its image and is not an input itself (the renders are
    # used as they come: framing refuses an object that touches the border, as this one does).
    out = tmp_path / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        report = infer_files(load_model(tiny_run.checkpoint, "cpu"), tmp_path, out, views=[], formats=["npz"],
                             frame=False)
    assert len(report.done) == 4 and not report.failed, [r.error for r in report.failed]
    assert not (out / "b_mask_sdf.npz").exists()  # four: a, b (its mask found), big, plain


def test_errors_name_the_file_or_argument(tiny_run, tmp_path, monkeypatch, capsys):
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"\x80\x02 not a checkpoint")
    with pytest.raises(ValueError, match="junk.ckpt"):
        load_model(junk, "cpu")
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(tiny_run.checkpoint.read_bytes()[:2000])
    with pytest.raises(ValueError, match="truncated.ckpt"):
        load_model(truncated, "cpu")
    foreign = tmp_path / "foreign.ckpt"
    torch.save({"state_dict": {"w": torch.zeros(1)}, "epoch": 0}, foreign)
    with pytest.raises(ValueError, match="foreign.ckpt.*not an SDFDiff"):
        load_model(foreign, "cpu")
    with pytest.raises(FileNotFoundError, match="missing.ckpt"):
        load_model(tmp_path / "missing.ckpt", "cpu")

    model = load_model(tiny_run.checkpoint, "cpu")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ValueError, match="bad.png"):
        load_image(bad)
    with pytest.raises(FileNotFoundError, match="nothere.png"):
        infer_files(model, [tmp_path / "nothere.png"], tmp_path / "o")
    Image.new("RGB", (64, 64), "white").save(tmp_path / "rgb.png")  # no mask, and nothing but background
    with pytest.raises(ValueError, match="rgb.png: cannot tell the object from the background.*mask"):
        load_image(tmp_path / "rgb.png")

    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(ValueError, match="output_dir"):
        infer_files(model, [bad], blocker / "sub")
    assert "bad.png" in expect_usage_error(main, [f"ckpt_path={tiny_run.checkpoint}", f"images=[{bad}]",
                                                  f"output_dir={tmp_path / 'o2'}"], monkeypatch, capsys, "sdfdiff-infer")
    assert "junk.ckpt" in expect_usage_error(main, [f"ckpt_path={junk}", f"images=[{bad}]",
                                                    f"output_dir={tmp_path / 'o3'}"], monkeypatch, capsys)
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device"):
            resolve_device("cuda")
    with pytest.raises(ValueError, match="device"):
        resolve_device("tpu")


@pytest.mark.cuda
def test_checkpoints_move_between_cpu_and_gpu(tiny_run, tmp_path):
    images = tiny_run.datamodule().dataset("test").views(0, [0, 9])
    on_cpu = load_model(tiny_run.checkpoint, "cpu")
    on_gpu = load_model(tiny_run.checkpoint, "cuda")
    assert on_gpu.device.type == "cuda"
    assert torch.allclose(predict(on_gpu, images).values.cpu(), predict(on_cpu, images).values, atol=1e-4)
    # A checkpoint whose tensors were saved on the GPU loads on the CPU.
    ckpt = torch.load(tiny_run.checkpoint, map_location="cuda", weights_only=True)
    gpu_file = tmp_path / "gpu.ckpt"
    torch.save(ckpt, gpu_file)
    back = load_model(gpu_file, "cpu")
    assert back.device.type == "cpu"
    assert torch.equal(predict(back, images).values, predict(on_cpu, images).values)
    recs = reconstruct_images(on_gpu, images[:1], views=[0], render_size=24)
    assert recs[0].watertight and recs[0].values.device.type == "cpu"


def test_a_checkpoint_cannot_name_arbitrary_callables(tiny_run, tmp_path):
    from svr.models.checkpoint_layout import CHECKPOINT_KEY

    ckpt = torch.load(tiny_run.checkpoint, map_location="cpu", weights_only=True)
    ckpt[CHECKPOINT_KEY]["model_config"] = {"_target_": "os.system", "command": "echo pwned"}
    crafted = tmp_path / "crafted.ckpt"
    torch.save(ckpt, crafted)
    with pytest.raises(ValueError, match="crafted.ckpt.*os.system"):
        load_model(crafted, "cpu")


def rgba_disc(path, inverted: bool = False, size: int = 64) -> Path:
    """An RGBA PNG of a grey disc on a transparent background (``inverted``: the disc transparent,
    the background opaque)."""
    yy, xx = np.mgrid[:size, :size]
    disc = (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (size / 4) ** 2
    u8 = np.full((4, size, size), 128, np.uint8)
    u8[3] = np.where(disc != inverted, 255, 0)
    save_rgba(u8, path)
    return path


def test_command_line_refuses_bad_settings_naming_the_key(tiny_run, tmp_path, monkeypatch, capsys):
    """Issue 17 items 9 and 10: each refusal is one line naming the setting, exit status 2."""
    image = rgba_disc(tmp_path / "disc.png")
    base = [f"ckpt_path={tiny_run.checkpoint}", f"images={image}", "device=cpu", "progress=false"]
    cases = {"batch_size=abc": "batch_size must be an integer, got 'abc'",
             "batch_size=-1": "batch_size must be an integer >= 1, got -1",
             "batch_size=0": "batch_size must be an integer >= 1, got 0",
             "render_size=0": "render_size must be an integer >= 1, got 0",
             "views=[99]": "views[0] must be an integer in [0, 23], got 99",
             "views=[3,3]": "views must not repeat"}
    for k, (override, message) in enumerate(cases.items()):
        out = tmp_path / f"out{k}"
        line = expect_usage_error(main, [*base, f"output_dir={out}", override], monkeypatch, capsys, "sdfdiff-infer")
        assert message in line, (override, line)
        assert not out.exists()  # the refused run left nothing behind
    # A random-bytes checkpoint: torch's advice to load with weights_only=False is never passed on.
    junk = tmp_path / "random.ckpt"
    junk.write_bytes(np.random.default_rng(0).bytes(300))
    line = expect_usage_error(main, [*base[1:], f"ckpt_path={junk}", f"output_dir={tmp_path / 'o'}"],
                              monkeypatch, capsys)
    assert "random.ckpt" in line and "weights_only" not in line
    with pytest.raises(ValueError) as err:
        load_model(junk, "cpu")
    assert "weights_only" not in str(err.value)
    # The Python API refuses them too (batch_size=-1 used to write nothing and report success).
    model = load_model(tiny_run.checkpoint, "cpu")
    for kwargs in ({"batch_size": -1}, {"batch_size": 0}, {"render_size": 0}, {"views": [99]}):
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            infer_files(model, [image], tmp_path / "api", **kwargs)


def test_an_image_above_the_decompression_bomb_limit_is_one_line(tiny_run, tmp_path, monkeypatch, capsys):
    image = rgba_disc(tmp_path / "huge.png")
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # 64 x 64 > 2 x 1000: PIL refuses to decode it
    line = expect_usage_error(main, [f"ckpt_path={tiny_run.checkpoint}", f"images={image}", "device=cpu",
                                     f"output_dir={tmp_path / 'out'}", "progress=false"], monkeypatch, capsys)
    assert "huge.png" in line and "too large" in line


def test_a_transparent_image_or_an_inverted_mask_is_refused(tiny_run, tmp_path, monkeypatch, capsys):
    """Issue 17 item 12: refused (not reconstructed as a blob), with a message saying which."""
    clear = tmp_path / "clear.png"
    Image.new("RGBA", (64, 64), (200, 100, 50, 0)).save(clear)
    with pytest.raises(ValueError, match="clear.png.*silhouette is empty"):
        load_image(clear)
    with pytest.raises(ValueError, match="inverted.png.*inverted"):
        load_image(rgba_disc(tmp_path / "inverted.png", inverted=True))
    # An RGB photo with a mask drawn the wrong way round (object black, background white).
    Image.new("RGB", (64, 64), "grey").save(tmp_path / "photo.png")
    mask = np.full((64, 64), 255, np.uint8)
    mask[20:44, 20:44] = 0
    Image.fromarray(mask, "L").save(tmp_path / "photo_mask.png")
    with pytest.raises(ValueError, match="photo_mask.png.*inverted"):
        load_image(tmp_path / "photo.png", tmp_path / "photo_mask.png")
    line = expect_usage_error(main, [f"ckpt_path={tiny_run.checkpoint}", f"images={clear}", "device=cpu",
                                     f"output_dir={tmp_path / 'out'}", "progress=false"], monkeypatch, capsys)
    assert "silhouette is empty" in line
    assert load_image(rgba_disc(tmp_path / "fine.png")).shape == (4, 64, 64)


def test_output_dir_is_the_run_folder(tiny_run, tmp_path, monkeypatch, capsys):
    """Issue 17 item 13: with output_dir given, nothing is made in the working directory."""
    image = rgba_disc(tmp_path / "disc.png")
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / "out"
    run_entry(main, [f"ckpt_path={tiny_run.checkpoint}", f"images={image}", "device=cpu", f"output_dir={out}",
                     "views=[]", "formats=[npz]", "progress=false"], monkeypatch)
    assert list(cwd.iterdir()) == []
    assert (out / "disc_sdf.npz").is_file() and (out / ".hydra" / "config.yaml").is_file()
    assert not list(out.glob("*.log"))  # hydra's empty log file is not left in the user's folder


def test_inference_from_a_read_only_working_directory(tiny_run, tmp_path):
    """Issue 17 item 13: a read-only working directory and a writable output_dir work. As root,
    to whom permission bits mean nothing, the command runs without the capabilities that override
    them."""
    image = rgba_disc(tmp_path / "disc.png")
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    cwd.chmod(0o555)
    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: cannot make a folder read-only")
        prefix = ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"]
    try:
        proc = subprocess.run([*prefix, sys.executable, "-m", "svr.infer", f"ckpt_path={tiny_run.checkpoint}",
                               f"images={image}", f"output_dir={tmp_path / 'out'}", "device=cpu", "views=[]",
                               "formats=[npz]", "progress=false"],
                              cwd=cwd, env={**os.environ, "PYTHONPATH": os.pathsep.join(
                                  [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])},
                              capture_output=True, text=True,
                              timeout=300)
    finally:
        cwd.chmod(0o755)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "out" / "disc_sdf.npz").is_file() and list(cwd.iterdir()) == []


def test_settings_are_built_from_infer_yaml():
    cfg = compose("infer", ["ckpt_path=x.ckpt", "images=[a.png,b.png]"])
    settings = build_settings(cfg)
    assert isinstance(settings, InferSettings) and isinstance(settings.paths, PathSettings)
    assert settings.images == ["a.png", "b.png"] and settings.output_dir is None and settings.masks is None
    assert settings.formats == ["npz", "ply", "obj", "png", "camera"] and settings.views == [0, 6, 12, 18]
    assert settings.input_view is None and settings.azimuth is None and settings.frame is None
    with pytest.raises(ValueError, match="input_view or azimuth, not both"):
        build_settings(compose("infer", ["ckpt_path=x.ckpt", "images=a.png", "input_view=1", "azimuth=30"]))
    with pytest.raises(ValueError, match="azimuth must be a finite number"):
        build_settings(compose("infer", ["ckpt_path=x.ckpt", "images=a.png", "azimuth=nan"]))
    with pytest.raises(ValueError, match="nonsense: unknown setting"):
        build_settings(compose("infer", ["ckpt_path=x.ckpt", "images=a.png", "+nonsense=1"]))
    with pytest.raises(TypeError, match="require_watertight must be"):
        build_settings(compose("infer", ["ckpt_path=x.ckpt", "images=a.png", "require_watertight=sometimes"]))


@pytest.mark.parametrize("override, message", [("+nonsense=1", "nonsense: unknown setting"),
                                               ("render_size=big", "render_size must be an integer, got 'big'"),
                                               ("formats=[stl]", "formats must be a non-empty list among")])
def test_a_bad_key_or_value_is_one_line_and_makes_no_folder(override, message, tmp_path, monkeypatch, capsys):
    """Checked when the settings are built: before the run folder, the model or the images."""
    lines = refused_before_any_folder(main, ["ckpt_path=missing.ckpt", "images=missing.png", override],
                                      "sdfdiff-infer", tmp_path, monkeypatch, capsys)
    assert all(message in line for line in lines), lines


def test_output_folder_loses_what_a_killed_write_left(tmp_path):
    """Issue 17 item 5: stale atomic-write temporaries in an output folder are removed when a command
    writes into it again."""
    from sdfcommon.tooling.outputs import ensure_output_dir

    left = tmp_path / ".chair_mesh.ply.0a1b2c3d.tmp"
    left.write_bytes(b"half a mesh")
    mine = tmp_path / "chair.ply"
    mine.write_bytes(b"a mesh")
    assert ensure_output_dir(tmp_path) == tmp_path
    assert not left.exists() and mine.read_bytes() == b"a mesh"
