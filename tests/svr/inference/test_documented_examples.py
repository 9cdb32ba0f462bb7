"""The inference examples the docs show run as written (issue 40 item 19): the Python example of
docs/svr_inference.md and every ``python -m svr.infer`` line of that page, the README and
configs/infer.yaml, on a checkpoint of a tiny ``model=pixel`` network made here (the demo's kind,
which reads the input camera and estimates it with its camera head), with input files of the names
the examples use."""
from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from PIL import Image

from sdfcommon.tooling.commands import compose
from svr.infer import main
from svr.models.checkpoint_layout import CHECKPOINT_KEY

from ...entry_points import run_entry

ROOT = Path(__file__).resolve().parents[3]
DOCUMENTED = ("docs/svr_inference.md", "README.md", "configs/infer.yaml")
# model=pixel at model=tiny's sizes (its head reads the input and the encoder's first two maps).
TINY_PIXEL = ["model=pixel", "model.encoder.channels=[8,16,32,32]", "model.encoder.latent_dim=64",
              "model.decoder.channels=[16,8,8]", "model.decoder.grid_resolution=32", "model.refiner.channels=[4,8]",
              "model.local.image_channels=[4,8,16]", "model.local.volume_channels=8", "model.local.hidden=16",
              "model.local.mirror_axis=null", "model.camera.elevation=false"]


@pytest.fixture(scope="module")
def pixel_checkpoint(tmp_path_factory) -> Path:
    """An untrained tiny model=pixel network saved as a checkpoint (its decoder starts as a sphere)."""
    config = OmegaConf.to_container(compose("train", TINY_PIXEL).model, resolve=True)
    torch.manual_seed(0)
    net = instantiate(config)
    assert net.needs_views
    path = tmp_path_factory.mktemp("pixel") / "pixel.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in net.state_dict().items()},
                CHECKPOINT_KEY: {"stage": "joint", "model_config": config}}, path)
    return path


def make_input(path: Path) -> None:
    """An input of the name an example uses: a folder (holding an RGBA image), an RGBA PNG, an RGB
    JPEG (on a plain white background) or (a name ending in ``_mask``) a mask; a grey disc on a
    transparent background."""
    if path.suffix == "":
        path.mkdir(parents=True, exist_ok=True)
        return make_input(path / "object.png")
    path.parent.mkdir(parents=True, exist_ok=True)
    yy, xx = np.mgrid[:64, :64]
    alpha = np.where((yy - 32) ** 2 + (xx - 32) ** 2 < 18 ** 2, 255, 0).astype(np.uint8)
    grey = np.full((64, 64, 3), 128, np.uint8)
    if path.stem.endswith("_mask"):
        Image.fromarray(alpha, "L").save(path)
    elif path.suffix.lower() in (".jpg", ".jpeg"):
        Image.fromarray(np.where(alpha[..., None] > 0, grey, 255).astype(np.uint8), "RGB").save(path)
    else:
        Image.fromarray(np.dstack([grey, alpha]), "RGBA").save(path)


def documented_command_lines() -> list[tuple[str, list[str]]]:
    """(where: "file:line", overrides) of every ``python -m svr.infer`` line in the documents (in
    YAML comments too)."""
    found = []
    for name in DOCUMENTED:
        for number, line in enumerate((ROOT / name).read_text().splitlines(), 1):
            text = line.lstrip("# ").strip()
            if text.startswith("python -m svr.infer "):
                found.append((f"{name}:{number}", shlex.split(text, comments=True)[3:]))
    return found


def python_example() -> str:
    text = (ROOT / "docs/svr_inference.md").read_text()
    return re.search(r"## From Python\s+```python\n(.*?)```", text, re.S).group(1)


def test_the_documents_show_the_examples():
    where = [w for w, _ in documented_command_lines()]
    assert len(where) >= 8 and any(w.startswith("README.md") for w in where), where
    assert "load_model" in python_example()


@pytest.mark.parametrize("where, overrides", documented_command_lines(), ids=[w for w, _ in documented_command_lines()])
def test_a_documented_command_line_runs(where, overrides, pixel_checkpoint, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for item in overrides:
        key, value = item.split("=", 1)
        entries = value.strip("[]").split(",")
        if key == "ckpt_path":
            Path(value).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(pixel_checkpoint, value)
        elif key in ("images", "masks"):
            for entry in entries:
                make_input(Path(entry.replace("*", "x")) if "*" in entry else Path(entry))
    extra = [] if any(o.startswith("output_dir=") for o in overrides) else ["output_dir=out"]
    run_entry(main, [*overrides, *extra, "views=[]", "progress=false"], monkeypatch)  # a failure raises SystemExit
    assert list(tmp_path.glob("*/*_sdf.npz")), where


def test_the_documented_python_example_runs(pixel_checkpoint, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copy(pixel_checkpoint, "best.ckpt")
    make_input(tmp_path / "photo.png")
    namespace: dict = {}
    exec(compile(python_example(), "docs/svr_inference.md", "exec"), namespace)
    assert namespace["grids"].values.shape == (1, 32, 32, 32)
    assert (tmp_path / "recon" / "photo_sdf.npz").is_file() and (tmp_path / "recon" / "photo_views.png").is_file()
