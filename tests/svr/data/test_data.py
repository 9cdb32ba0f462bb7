"""The NMR format: a fake two-category dataset written here, loading, background fix, preparation
into memory-mapped arrays, clear errors on bad files, the DataModules and their hydra configs."""
from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from svr.data.datamodules import NMRDataModule, ProceduralDataModule
from svr.data.datasets import EvalViews, NMRDataset
from svr.data.samplers import ObjectViewSampler
from svr.data.types import SVRBatch
from svr.nmr.format import images_to_float, nmr_file, prepare_nmr, read_npz_header

CATS = {"02691156": 3, "03001627": 2}  # airplane, chair: objects per split
REPO = Path(__file__).resolve().parents[3]


def _images(n: int, rng: np.random.Generator, black: bool = False) -> np.ndarray:
    img = np.zeros((n, 24, 4, 64, 64), np.uint8)
    img[:, :, 3, 20:40, 20:44] = 255
    img[:, :, 3, 19, 20:44] = 128  # an anti-aliased edge
    img[:, :, :3] = rng.integers(0, 256, size=(n, 24, 3, 64, 64), dtype=np.uint8)
    a = img[:, :, 3:4].astype(np.float64) / 255
    bg = 0 if black else 255
    img[:, :, :3] = np.round(img[:, :, :3] * a + bg * (1 - a)).astype(np.uint8)
    img[:, :, 0, 0, 0] = np.arange(n * 24).reshape(n, 24) % 251 if not black else 0  # tag (object, view)
    return img


def write_fake_nmr(root: Path, black: bool = False, seed: int = 0) -> dict:
    """The exact NMR layout for two categories and three splits; returns the arrays written."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    data = {}
    for cid, n in CATS.items():
        for split in ("train", "val", "test"):
            img = _images(n, rng, black)
            vox = rng.random((n, 32, 32, 32)) < 0.2
            np.savez_compressed(nmr_file(root, cid, split, "images"), img)
            np.savez_compressed(nmr_file(root, cid, split, "voxels"), vox)
            data[cid, split] = (img, vox)
    return data


@pytest.fixture()
def fake_nmr(tmp_path) -> tuple[Path, dict]:
    root = tmp_path / "nmr"
    return root, write_fake_nmr(root)


# ------------------------------------------------------------------------------------ dataset


def test_fake_nmr_dataset_loads(fake_nmr):
    root, data = fake_nmr
    ds = NMRDataset(root, "val", categories=["02691156", "chair"])
    assert ds.categories == [("02691156", "airplane"), ("03001627", "chair")]
    assert len(ds) == 5 and ds.counts == [3, 2]
    item = ds[4]
    assert item["category"] == 1 and item["category_name"] == "chair" and item["object_index"] == 1
    assert item["images"].shape == (24, 4, 64, 64) and item["images"].dtype == torch.float32
    assert item["voxels"].shape == (32, 32, 32) and item["voxels"].dtype == torch.bool
    assert item["view_ids"].tolist() == list(range(24))
    assert item["azimuth_deg"][3].item() == -45.0
    img, vox = data["03001627", "val"]
    np.testing.assert_allclose(item["images"].numpy(), img[1] / 255.0, atol=1e-7)  # white background: unchanged
    np.testing.assert_array_equal(item["voxels"].numpy(), vox[1])
    np.testing.assert_array_equal(ds.images_uint8(0, [5, 2]), data["02691156", "val"][0][0, [5, 2]])
    assert not ds.prepared


def test_default_categories_are_the_13_nmr_ones(fake_nmr):
    root, _ = fake_nmr
    with pytest.raises(FileNotFoundError, match=r"02828884_test_images\.npz"):
        NMRDataset(root, "test")  # bench is the first of the 13 that the fake folder lacks


def test_black_background_is_detected_and_fixed():
    rng = np.random.default_rng(1)
    black = _images(1, rng, black=True)[0]
    white = _images(1, rng, black=False)[0]
    fixed = images_to_float(black)
    alpha = black[:, 3] / 255.0
    clear = alpha == 0
    assert torch.all(fixed[:, :3].permute(1, 0, 2, 3)[:, torch.from_numpy(clear)] == 1.0)  # now white
    rgb = black[:, :3] / 255.0 + (1 - alpha[:, None])
    np.testing.assert_allclose(fixed[:, :3].numpy(), np.clip(rgb, 0, 1), atol=1e-6)
    np.testing.assert_allclose(images_to_float(white).numpy(), white / 255.0, atol=1e-7)
    np.testing.assert_allclose(images_to_float(black, "invert")[:, :3].numpy(), 1 - black[:, :3] / 255.0, atol=1e-6)
    np.testing.assert_allclose(images_to_float(black, "keep").numpy(), black / 255.0, atol=1e-7)
    with pytest.raises(ValueError, match="black_background"):
        images_to_float(black, "grey")


# ------------------------------------------------------------------------------------ preparation


def test_prepare_writes_memory_mapped_arrays_atomically(fake_nmr):
    root, data = fake_nmr
    paths = prepare_nmr(root, categories=list(CATS), progress=False)
    assert len(paths) == 2 * 3 * 2
    assert not [p for p in root.iterdir() if p.name.endswith(".tmp")]
    arr = np.load(nmr_file(root, "02691156", "train", "images", "npy"), mmap_mode="r")
    assert isinstance(arr, np.memmap) and arr.shape == (3, 24, 4, 64, 64) and arr.dtype == np.uint8
    ds = NMRDataset(root, "train", categories=list(CATS))
    assert ds.prepared
    assert isinstance(ds._open()[0][0], np.memmap)
    np.testing.assert_array_equal(ds.images_uint8(3), data["03001627", "train"][0][0])
    np.testing.assert_array_equal(ds.voxels(1).numpy(), data["02691156", "train"][1][1])
    # idempotent: existing valid files are kept
    mtime = nmr_file(root, "02691156", "train", "images", "npy").stat().st_mtime_ns
    prepare_nmr(root, categories=list(CATS), progress=False)
    assert nmr_file(root, "02691156", "train", "images", "npy").stat().st_mtime_ns == mtime


def _script(name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / "data" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_prepared_dir_elsewhere_and_the_script(fake_nmr, tmp_path, capsys):
    root, _ = fake_nmr
    out = tmp_path / "prepared"
    script = _script("prepare_nmr")
    assert script.main([str(root), "--out", str(out), "--categories", "airplane", "chair", "--splits", "test"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        f"{c}_test_{k}.npy" for c in CATS for k in ("images", "voxels"))
    ds = NMRDataset(root, "test", categories=list(CATS), prepared_dir=out)
    assert ds.prepared
    assert script.main([str(tmp_path / "nope")]) == 1
    assert "does not exist" in capsys.readouterr().err


def test_workers_share_the_memory_map_instead_of_copies(fake_nmr):
    root, _ = fake_nmr
    prepare_nmr(root, categories=list(CATS), progress=False)
    ds = NMRDataset(root, "train", categories=list(CATS))
    ds[0]
    assert ds._arrays is not None
    blob = pickle.dumps(ds)
    assert len(blob) < 20_000  # no arrays travel to the workers
    clone = pickle.loads(blob)
    assert clone._arrays is None and torch.equal(clone[0]["voxels"], ds[0]["voxels"])


# ------------------------------------------------------------------------------------ errors


def test_missing_file_is_named(fake_nmr):
    root, _ = fake_nmr
    victim = nmr_file(root, "03001627", "val", "voxels")
    victim.unlink()
    with pytest.raises(FileNotFoundError, match=str(victim)):
        NMRDataset(root, "val", categories=list(CATS))
    with pytest.raises(FileNotFoundError, match=str(victim)):
        prepare_nmr(root, categories=list(CATS), progress=False)


def test_wrong_shape_is_named(fake_nmr):
    root, _ = fake_nmr
    victim = nmr_file(root, "02691156", "test", "images")
    np.savez_compressed(victim, np.zeros((3, 24, 3, 64, 64), np.uint8))
    with pytest.raises(ValueError, match=rf"{victim}.*shape \(3, 24, 3, 64, 64\).*expected \(N, 24, 4, 64, 64\)"):
        NMRDataset(root, "test", categories=list(CATS))
    victim = nmr_file(root, "02691156", "train", "voxels")
    np.savez_compressed(victim, np.zeros((3, 64, 64, 64), bool))
    with pytest.raises(ValueError, match=rf"{victim}.*expected \(N, 32, 32, 32\)"):
        prepare_nmr(root, categories=list(CATS), progress=False)


def test_wrong_dtype_and_mismatched_counts_are_named(fake_nmr):
    root, _ = fake_nmr
    victim = nmr_file(root, "03001627", "val", "images")
    np.savez_compressed(victim, np.zeros((2, 24, 4, 64, 64), np.float32))
    with pytest.raises(ValueError, match=rf"{victim}.*dtype float32"):
        NMRDataset(root, "val", categories=list(CATS))
    np.savez_compressed(victim, np.zeros((4, 24, 4, 64, 64), np.uint8))
    with pytest.raises(ValueError, match=rf"{victim} holds 4 objects but .*03001627_val_voxels\.npz holds 2"):
        NMRDataset(root, "val", categories=list(CATS))


def test_truncated_npz_is_named(fake_nmr):
    root, _ = fake_nmr
    victim = nmr_file(root, "03001627", "train", "images")
    blob = victim.read_bytes()
    victim.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(ValueError, match=rf"{victim} is truncated or corrupt"):
        read_npz_header(victim)
    with pytest.raises(ValueError, match=rf"{victim} is truncated or corrupt"):
        NMRDataset(root, "train", categories=list(CATS))
    with pytest.raises(ValueError, match=rf"{victim} is truncated or corrupt"):
        prepare_nmr(root, categories=list(CATS), progress=False)
    assert not [p for p in root.iterdir() if p.name.endswith(".tmp")]


def test_truncated_prepared_array_is_named(fake_nmr):
    root, _ = fake_nmr
    prepare_nmr(root, categories=list(CATS), progress=False)
    victim = nmr_file(root, "02691156", "val", "images", "npy")
    with open(victim, "r+b") as f:
        f.truncate(victim.stat().st_size - 1000)
    with pytest.raises(ValueError, match=rf"{victim} is truncated"):
        NMRDataset(root, "val", categories=list(CATS))
    # preparing again repairs it
    prepare_nmr(root, categories=list(CATS), progress=False)
    assert NMRDataset(root, "val", categories=list(CATS)).prepared


def test_bad_arguments_are_refused(fake_nmr, tmp_path):
    root, _ = fake_nmr
    with pytest.raises(ValueError, match="split must be one of"):
        NMRDataset(root, "validation")
    with pytest.raises(ValueError, match="unknown category 'teapot'"):
        NMRDataset(root, "val", categories=["teapot"])
    with pytest.raises(FileNotFoundError, match="does not exist"):
        NMRDataset(tmp_path / "missing", "val")
    with pytest.raises(ValueError, match="root must name"):
        NMRDataModule(None)
    with pytest.raises(FileNotFoundError, match=str(tmp_path / "missing")):
        NMRDataModule(tmp_path / "missing")
    with pytest.raises(ValueError, match="views_per_sample"):
        NMRDataModule(root, views_per_sample=25)
    with pytest.raises(ValueError, match=r"views\[0\] must be an integer in \[0, 23\], got 24"):
        EvalViews(NMRDataset(root, "val", categories=list(CATS)), views=[24])
    with pytest.raises(ValueError, match="views must not repeat"):
        EvalViews(NMRDataset(root, "val", categories=list(CATS)), views=[3, 3])



def test_built_data_is_not_described_as_nmr_shapenet(fake_nmr):
    """A folder of the benchmark's ids is NMR ShapeNet until a metadata.json says a tool made it
    (the mesh builder writes one): evaluation then labels it NMR-format data, without the paper's rows."""
    root, _ = fake_nmr
    assert NMRDataModule(root).describe() == f"NMR ShapeNet ({root})"
    (root / "metadata.json").write_text(json.dumps({"builder_version": 2, "categories": []}))
    assert NMRDataModule(root).describe() == f"NMR-format data ({root})"


# ------------------------------------------------------------------------------------ sampling


def test_sampler_draws_distinct_views_reproducibly():
    s = ObjectViewSampler([3, 0, 5], views_per_sample=3, samples_per_epoch=400, seed=7)
    a = list(s)
    assert len(a) == 400 and all(len(set(v)) == 3 for _, v in a)
    assert {o for o, _ in a} == set(range(8))
    assert a == list(s)  # same epoch, same draws
    s.set_epoch(1)
    assert list(s) != a
    bal = ObjectViewSampler([1, 99], 2, 4000, seed=0, category_balanced=True)
    share = np.mean([o == 0 for o, _ in bal])
    assert 0.45 < share < 0.55
    with pytest.raises(ValueError, match="no objects"):
        ObjectViewSampler([0, 0])


def test_datamodule_batches_follow_the_contract(fake_nmr):
    root, data = fake_nmr
    dm = NMRDataModule(root, categories=["airplane", "chair"], batch_size=4, eval_batch_size=7,
                       samples_per_epoch=12, num_workers=2, seed=3)
    assert dm.categories == [("02691156", "airplane"), ("03001627", "chair")] and dm.shading is None
    dm.prepare_data()
    dm.setup("fit")
    batches = list(dm.train_dataloader())
    assert len(batches) == 3
    b = batches[0]
    assert isinstance(b, SVRBatch)
    assert b.images.shape == (4, 2, 4, 64, 64) and b.images.dtype == torch.float32
    assert b.view_ids.shape == (4, 2) and b.view_ids.dtype == torch.long
    assert all(v[0] != v[1] for v in b.view_ids.tolist())
    assert b.voxels.shape == (4, 32, 32, 32) and b.voxels.dtype == torch.bool
    for k in range(4):  # each element is its object's views and voxels
        cid = dm.categories[int(b.category[k])][0]
        img, vox = data[cid, "train"]
        o = int(b.object_index[k])
        np.testing.assert_allclose(b.images[k].numpy(), img[o, b.view_ids[k].numpy()] / 255.0, atol=1e-7)
        np.testing.assert_array_equal(b.voxels[k].numpy(), vox[o])
    # evaluation: every (object, view), in order, V = 1
    val = list(dm.val_dataloader())
    images = torch.cat([x.images for x in val])
    assert images.shape == (5 * 24, 1, 4, 64, 64)
    views = torch.cat([x.view_ids for x in val]).squeeze(1)
    cats = torch.cat([x.category for x in val])
    objs = torch.cat([x.object_index for x in val])
    assert views.tolist() == list(range(24)) * 5
    assert cats.tolist() == [0] * 72 + [1] * 48 and objs.tolist()[::24] == [0, 1, 2, 0, 1]
    dm.setup("test")
    assert len(dm.test_dataloader().dataset) == 5 * 24


def test_validation_can_be_thinned(fake_nmr):
    root, _ = fake_nmr
    dm = NMRDataModule(root, categories=list(CATS), val_views=[0, 12], val_objects_per_category=1,
                       eval_batch_size=100, prepare=False)
    b = next(iter(dm.val_dataloader()))
    assert b.view_ids.squeeze(1).tolist() == [0, 12, 0, 12] and b.category.tolist() == [0, 0, 1, 1]


def test_procedural_datamodule_uses_its_cache(tiny_procedural):
    cache, root, settings = tiny_procedural
    dm = ProceduralDataModule(cache_dir=cache, categories=list(settings.categories), train=settings.train,
                              val=settings.val, test=settings.test, data_seed=settings.seed,
                              supersample=settings.supersample, batch_size=2, progress=False)
    assert dm.root == root
    assert dm.shading is None  # per-part colours under an unknown light, as NMR ShapeNet
    assert [n for _, n in dm.categories] == ["chair", "mug", "lamp"]
    dm.prepare_data()
    dm.setup("fit")
    b = next(iter(dm.train_dataloader()))
    assert b.images.shape == (2, 2, 4, 64, 64)
    alpha = b.images[:, :, 3]
    rgb = b.images[:, :, :3]
    assert torch.all(rgb.permute(0, 1, 3, 4, 2)[alpha == 0] == 1.0)  # white background


# ------------------------------------------------------------------------------------ hydra


def _compose(overrides: list[str]):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(REPO / "configs"), version_base=None):
        return compose(config_name=None, overrides=overrides)


def test_hydra_configs_instantiate_plain_objects(fake_nmr, tiny_procedural):
    from hydra.utils import instantiate

    root, _ = fake_nmr
    cfg = _compose(["+data=nmr", f"data.root={root}", "data.categories=[airplane,chair]", "data.val_views=[1,2]"])
    dm = instantiate(cfg.data)
    assert isinstance(dm, NMRDataModule) and dm.categories[1] == ("03001627", "chair")
    assert dm.val_views == [1, 2] and type(dm.val_views) is list
    cache, root_p, s = tiny_procedural
    cfg = _compose(["+data=procedural", f"data.cache_dir={cache}", "data.categories=[chair,mug,lamp]",
                    f"data.train={s.train}", f"data.val={s.val}", f"data.test={s.test}", f"data.data_seed={s.seed}",
                    f"data.supersample={s.supersample}"])
    dm = instantiate(cfg.data)
    assert isinstance(dm, ProceduralDataModule) and dm.root == root_p and dm.seed == 0


def test_nmr_config_requires_an_existing_root(tmp_path):
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate
    from omegaconf.errors import MissingMandatoryValue

    with pytest.raises(MissingMandatoryValue, match="data.root"):
        instantiate(_compose(["+data=nmr"]).data)
    missing = tmp_path / "no-such-folder"
    with pytest.raises(InstantiationException, match=f"NMR data folder does not exist: {missing}"):
        instantiate(_compose(["+data=nmr", f"data.root={missing}"]).data)


def test_make_procedural_script_reuses_the_cache(tiny_procedural, capsys):
    cache, root, s = tiny_procedural
    args = ["--cache-dir", str(cache), "--categories", *s.categories, "--train", str(s.train), "--val", str(s.val),
            "--test", str(s.test), "--seed", str(s.seed), "--supersample", str(s.supersample)]
    assert _script("make_procedural").main(args) == 0
    assert str(root) in capsys.readouterr().out


def test_outside_the_checkout_data_goes_to_the_user_cache_and_generation_says_where(tmp_path, monkeypatch, capsys):
    from sdfcommon.tooling.commands import compose, project_checkout

    monkeypatch.chdir(project_checkout())
    assert compose("train").paths.data_dir == "data/cache"  # the README's commands, run in the checkout
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "user-cache"))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert compose("train").paths.data_dir == str(tmp_path / "user-cache" / "sdfdiff")
    dm = ProceduralDataModule(categories=["mug"], train=1, val=1, test=1, supersample=1, progress=False,
                              generation_workers=0)
    assert dm.root.parent == tmp_path / "user-cache" / "sdfdiff"
    dm.prepare_data()
    said = capsys.readouterr().err
    assert f"(3 objects, about 1 MB) into {dm.root};" in said and "paths.data_dir" in said
    assert (dm.root / "metadata.json").exists() and list(elsewhere.iterdir()) == []
    dm.prepare_data()  # present: nothing generated, nothing said
    assert "Generating" not in capsys.readouterr().err


def test_relative_cache_dir_is_taken_from_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    dm = ProceduralDataModule(cache_dir="data/cache", train=1, val=1, test=1, progress=False)
    assert dm.cache_dir == tmp_path / "data" / "cache" and dm.root.parent == tmp_path / "data" / "cache"
    assert os.path.basename(dm.root).startswith("procedural-")
