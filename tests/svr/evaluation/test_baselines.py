"""svr.evaluation.baselines: mean shapes, retrieval and the oracle, scored on an evaluation's images; their rows
in the evaluation table."""
from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from svr.data.datasets import NMRDataset
from svr.data.procedural.generator import dataset_shape
from svr.evaluation.baselines import (BASELINES, READS, SIDE_BASELINES, category_mean_shapes, check_baselines,
                                      mean_shape, oracle_voxels, protocol_voxels_of_voxels, retrieve,
                                      retrieve_any_view, score_baselines, score_baselines_and_sides)
from svr.evaluation.protocol import model_reads
from svr.evaluation.tables import EvaluationResult, format_table, table_rows, write_report
from svr.inference.calibration import Calibration
from svr.inference.prediction import LoadedModel
from svr.nmr.format import NMR_CATEGORIES, nmr_file, prepare_nmr
from svr.nmr.metrics import voxel_iou


class VoxelSet:
    """The part of NMRDataset the mean shapes read."""

    def __init__(self, voxels: torch.Tensor, counts: list[int]):
        self._voxels = voxels
        self.counts = counts
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    def __len__(self) -> int:
        return len(self._voxels)

    def voxels(self, i: int) -> torch.Tensor:
        return self._voxels[i]


def test_mean_shape_is_scored_through_the_protocol():
    a = torch.zeros(3, 32, 32, 32, dtype=torch.bool)
    a[:, 8:24, 8:24, 8:24] = True    # a core every object shares
    a[0, 2:8, :, :] = True           # one object's own slab
    shape, threshold = mean_shape(VoxelSet(a, [3]))
    # The slab is in 1 of 3 objects: the best constant shape is the core, as the protocol sees it
    # (marching cubes of its SDF, then the benchmark's dilated voxelisation).
    assert torch.equal(shape, protocol_voxels_of_voxels(a[1]))
    assert shape.sum() > a[1].sum() and (shape & a[1]).sum() == a[1].sum()
    best = float(voxel_iou(shape.expand_as(a), a).mean())
    assert best > float(voxel_iou(protocol_voxels_of_voxels(a[0]).expand_as(a), a).mean())
    assert 0.05 <= threshold <= 0.95
    with pytest.raises(ValueError, match="non-empty"):
        mean_shape(VoxelSet(torch.zeros(0, 32, 32, 32, dtype=torch.bool), [0]))


def test_category_mean_shapes_are_told_the_category():
    cube = torch.zeros(32, 32, 32, dtype=torch.bool)
    cube[10:22, 10:22, 10:22] = True
    slab = torch.zeros(32, 32, 32, dtype=torch.bool)
    slab[4:8, 2:30, 2:30] = True
    shapes = category_mean_shapes(VoxelSet(torch.stack([cube, cube, slab, slab]), [2, 2]))
    # Each category's objects are identical: its mean SDF is theirs, and the best level fits them best.
    for c, obj in ((0, cube), (1, slab)):
        assert float(voxel_iou(shapes[c], obj)) >= float(voxel_iou(protocol_voxels_of_voxels(obj), obj)) - 1e-9
        assert float(voxel_iou(shapes[c], obj)) > 0.7
    assert float(voxel_iou(shapes[0], slab)) < 0.1


def _write_nmr_folder(root, counts: dict[str, dict[str, int]], seed: int = 0):
    """An NMR-format folder of random silhouettes and voxels: {category id: {split: objects}}."""
    rng = np.random.default_rng(seed)
    arrays = {}
    for cid, sizes in counts.items():
        for split, n in sizes.items():
            images = np.zeros((n, 24, 4, 64, 64), dtype=np.uint8)
            images[:, :, 3] = (rng.random((n, 24, 64, 64)) < 0.4) * 255
            voxels = rng.random((n, 32, 32, 32)) < 0.3
            arrays[(cid, split)] = [images, voxels]
    return arrays


def _save(root, arrays):
    root.mkdir(parents=True, exist_ok=True)
    for (cid, split), (images, voxels) in arrays.items():
        np.savez_compressed(nmr_file(root, cid, split, "images"), images)
        np.savez_compressed(nmr_file(root, cid, split, "voxels"), voxels)


def _result_over(objects: NMRDataset, views) -> EvaluationResult:
    """An EvaluationResult skeleton over every object of a split and the given views."""
    cat, obj, view = [], [], []
    for g in range(len(objects)):
        c, o = objects.locate(g)
        for v in views:
            cat.append(c), obj.append(o), view.append(v)
    n = len(cat)
    return EvaluationResult(split=objects.split, dataset="test", categories=tuple(objects.categories),
                            is_nmr_shapenet=True, checkpoint=None, stage="joint", output="refined",
                            category=np.array(cat), object_index=np.array(obj), view=np.array(view),
                            iou=np.full(n, 0.5))


def test_retrieval_finds_an_identical_training_object(tmp_path):
    ids = [NMR_CATEGORIES[0][0], NMR_CATEGORIES[4][0]]  # airplane, chair
    arrays = _write_nmr_folder(tmp_path, {ids[0]: {"train": 3, "test": 2}, ids[1]: {"train": 3, "test": 1}})
    # Test objects that are copies of training objects (one from the other category: retrieval is
    # not told the category).
    for (src_c, src_o), (dst_c, dst_o) in ((((ids[0], 2)), (ids[0], 0)), ((ids[0], 1), (ids[1], 0))):
        for k in range(2):
            arrays[(dst_c, "test")][k][dst_o] = arrays[(src_c, "train")][k][src_o]
    _save(tmp_path, arrays)
    prepare_nmr(tmp_path, categories=ids, splits=("train", "test"), progress=False)  # memory-mapped, as NMR data is read
    train, test = NMRDataset(tmp_path, "train", categories=ids), NMRDataset(tmp_path, "test", categories=ids)
    result = _result_over(test, range(24))
    scores = score_baselines(["retrieval", "oracle"], result, test, train, 0.6, 64, progress=False)
    assert list(scores) == ["retrieval"]  # no oracle on data without analytic shapes
    copies = ((result.category == 0) & (result.object_index == 0)) | (result.category == 1)
    np.testing.assert_array_equal(scores["retrieval"][copies], 1.0)
    assert scores["retrieval"][~copies].max() < 0.5  # random voxels of another object
    # The index itself, per view, for the copy of training object 2 (global index 2).
    queries = np.stack([test.images_uint8(0, [v])[0, 3] for v in range(24)])
    np.testing.assert_array_equal(retrieve(train, queries, np.arange(24)), 2)
    np.testing.assert_array_equal(retrieve(train, queries[:4], np.arange(4), chunk=1), 2)


class SilhouetteBank:
    """The part of NMRDataset the retrievals read: (N, 24, H, W) uint8 alpha."""

    def __init__(self, alpha: np.ndarray):
        self.alpha = alpha

    def __len__(self) -> int:
        return len(self.alpha)

    def silhouettes(self, view: int) -> np.ndarray:
        return self.alpha[:, view]


def _random_alpha(rng, *shape) -> np.ndarray:
    return ((rng.random((*shape, 64, 64)) < 0.4) * 255).astype(np.uint8)


def test_retrieval_any_view_finds_a_copy_seen_from_another_view():
    rng = np.random.default_rng(1)
    bank = SilhouetteBank(_random_alpha(rng, 6, 24))
    queries = np.stack([bank.alpha[4, 17], bank.alpha[2, 0], bank.alpha[5, 23]])
    # The query of view 3 is training object 4's view 17: found without the camera; the camera-bound
    # retrieval compares view 3 only, where object 4 looks like any other.
    np.testing.assert_array_equal(retrieve_any_view(bank, queries), [4, 2, 5])
    np.testing.assert_array_equal(retrieve_any_view(bank, queries, chunk=1), [4, 2, 5])
    assert retrieve(bank, queries[:1], np.array([3]))[0] != 4 or np.array_equal(bank.alpha[4, 3], queries[0])


def test_retrieval_any_view_matches_a_brute_force_search():
    rng = np.random.default_rng(2)
    # Smooth-ish silhouettes (discs of random centre and radius), so the scores spread out.
    yx = np.stack(np.meshgrid(np.arange(64), np.arange(64), indexing="ij"), -1)
    centres, radii = rng.uniform(16, 48, (7 * 24 + 5, 2)), rng.uniform(6, 20, 7 * 24 + 5)
    discs = ((np.linalg.norm(yx[None] - centres[:, None, None], axis=-1) < radii[:, None, None]) * 255).astype(np.uint8)
    bank, queries = SilhouetteBank(discs[:7 * 24].reshape(7, 24, 64, 64)), discs[7 * 24:]
    f = lambda a: a.astype(np.float64).reshape(len(a), 32, 2, 32, 2).mean((2, 4)).reshape(len(a), -1) / 255.0
    q, b = f(queries), f(bank.alpha.reshape(-1, 64, 64))
    inter = q @ b.T
    iou = inter / (q.sum(1)[:, None] + b.sum(1)[None] - inter)
    expected = iou.reshape(len(q), 7, 24).max(2).argmax(1)
    np.testing.assert_array_equal(retrieve_any_view(bank, queries, chunk=2), expected)


def test_retrieval_any_view_ties_and_edges():
    rng = np.random.default_rng(3)
    alpha = _random_alpha(rng, 4, 24)
    query = _random_alpha(rng, 1)[0]
    alpha[3, 0] = query    # seen first (view 0) ...
    alpha[1, 20] = query   # ... but a lower index with the same score wins
    bank = SilhouetteBank(alpha)
    assert retrieve_any_view(bank, query[None])[0] == 1
    # An empty query scores 0 against everything: the lowest index.
    assert retrieve_any_view(bank, np.zeros((1, 64, 64), np.uint8))[0] == 0
    assert retrieve_any_view(bank, np.zeros((0, 64, 64), np.uint8)).shape == (0,)
    with pytest.raises(ValueError, match="queries"):
        retrieve_any_view(bank, query)
    with pytest.raises(ValueError, match="non-empty"):
        retrieve_any_view(SilhouetteBank(np.zeros((0, 24, 64, 64), np.uint8)), query[None])
    with pytest.raises(ValueError, match="chunk"):
        retrieve_any_view(bank, query[None], chunk=0)


def test_retrieval_any_view_scores_rotated_copies_exactly(tmp_path):
    ids = [NMR_CATEGORIES[0][0], NMR_CATEGORIES[4][0]]
    arrays = _write_nmr_folder(tmp_path, {ids[0]: {"train": 3, "test": 1}, ids[1]: {"train": 2, "test": 1}})
    # Test object 0 of the first category is training object 1 turned by 5 views (its view v is the
    # training object's view v + 5), with the same voxels: the camera-free lookup finds it in every view.
    images, voxels = arrays[(ids[0], "train")]
    arrays[(ids[0], "test")][0][0] = np.roll(images[1], -5, axis=0)
    arrays[(ids[0], "test")][1][0] = voxels[1]
    _save(tmp_path, arrays)
    prepare_nmr(tmp_path, categories=ids, splits=("train", "test"), progress=False)
    train, test = NMRDataset(tmp_path, "train", categories=ids), NMRDataset(tmp_path, "test", categories=ids)
    result = _result_over(test, range(0, 24, 3))
    scores = score_baselines(["retrieval", "retrieval_any_view"], result, test, train, 0.6, 64, progress=False)
    copy = result.category == 0
    np.testing.assert_array_equal(scores["retrieval_any_view"][copy], 1.0)
    # The camera-bound lookup compares each view with the original's same view, another random image:
    # it finds the original only by chance.
    assert scores["retrieval"][copy].mean() < 0.5
    assert scores["retrieval_any_view"][~copy].max() < 0.5


def test_side_views_of_a_retrieved_object_are_its_stored_silhouettes(tmp_path):
    """A retrieved training object's side-view IoU compares its stored alpha in the two views 90
    degrees either side of the input with the image's object's: 1 for an identical copy, and for
    any other pair the mean of the two silhouette IoUs, computed here by hand."""
    ids = [NMR_CATEGORIES[0][0], NMR_CATEGORIES[4][0]]
    arrays = _write_nmr_folder(tmp_path, {ids[0]: {"train": 3, "test": 2}, ids[1]: {"train": 2, "test": 1}})
    for k in range(2):  # test object 0 of the first category is training object 2
        arrays[(ids[0], "test")][k][0] = arrays[(ids[0], "train")][k][2]
    _save(tmp_path, arrays)
    prepare_nmr(tmp_path, categories=ids, splits=("train", "test"), progress=False)
    train, test = NMRDataset(tmp_path, "train", categories=ids), NMRDataset(tmp_path, "test", categories=ids)
    result = _result_over(test, [0, 7, 20])
    scores = score_baselines_and_sides(["retrieval", "mean_shape", "oracle"], result, test, train, 0.6, 64,
                                       progress=False)
    assert list(scores.side_iou) == ["retrieval"]  # the others have no side views to show (SIDE_BASELINES)
    side = scores.side_iou["retrieval"]
    copy = (result.category == 0) & (result.object_index == 0)
    np.testing.assert_array_equal(side[copy], 1.0)
    glob = np.asarray(test.offsets)[result.category] + result.object_index
    alphas = [test.images_uint8(int(g), [int(v)])[0, 3] for g, v in zip(glob, result.view)]
    found = retrieve(train, np.stack(alphas), result.view)
    for i in np.flatnonzero(~copy):
        ious = []
        for s in ((result.view[i] + 6) % 24, (result.view[i] - 6) % 24):  # 7 -> 13 and 1; 20 -> 2 and 14
            a = train.images_uint8(int(found[i]), [int(s)])[0, 3] >= 128
            b = test.images_uint8(int(glob[i]), [int(s)])[0, 3] >= 128
            ious.append((a & b).sum() / (a | b).sum())
        assert side[i] == pytest.approx(np.mean(ious), abs=1e-12)
    assert side[~copy].max() < 0.5  # random silhouettes of density 0.4 overlap by about 0.25
    assert score_baselines(["retrieval"], result, test, train, 0.6, 64, progress=False).keys() == {"retrieval"}
    assert not score_baselines_and_sides(["retrieval"], result, test, train, 0.6, 64, progress=False,
                                         sides=False).side_iou


def test_a_category_mean_is_rendered_at_the_stored_images_size():
    """Built datasets may store 128^2 images: the mean shape is rendered at the stored size; an
    object whose stored side views are that shape's own renders scores 1 from the side."""
    from svr.evaluation.baselines import _rendered_side_iou
    from svr.nmr.side_views import render_silhouettes
    from svr.nmr.voxels import voxels_to_sdf

    cube = torch.zeros(32, 32, 32, dtype=torch.bool)
    cube[8:24, 12:20, 4:28] = True  # a box, longer along one axis: its side views differ
    values, _, hi = voxels_to_sdf(cube.numpy())
    own = render_silhouettes(torch.from_numpy(values).float()[None], hi, torch.arange(24)[None], image_size=32)[0]

    class Stored:  # two objects: the shape's own renders, and an empty one
        def silhouettes(self, view):
            return np.stack([own[view].numpy().astype(np.uint8) * 255, np.zeros((32, 32), np.uint8)])

    side = _rendered_side_iou({0: cube}, np.array([0, 0, 0]), Stored(), np.array([0, 0, 1]), np.array([0, 5, 0]))
    np.testing.assert_allclose(side, [1.0, 1.0, 0.0])


def test_oracle_and_baselines_on_procedural_data(tiny_procedural):
    """The oracle is the exact shape on the model's grid: at least 0.97 at 64^3 against the default
    (protocol) ground truth, lower on a coarser grid; every baseline gives one IoU per image."""
    cache, root, settings = tiny_procedural
    assert settings.voxel_rule == "protocol"
    test, train = NMRDataset(root, "test"), NMRDataset(root, "train")
    result = _result_over(test, [0, 5])
    both = score_baselines_and_sides(BASELINES, result, test, train, 0.6, 64, progress=False)
    scores = both.iou
    assert list(scores) == list(BASELINES) and list(both.side_iou) == list(SIDE_BASELINES)
    for name, values in both.side_iou.items():
        assert values.shape == result.iou.shape and np.all((values >= 0) & (values <= 1)), name
    # The category's mean shape, rendered, looks from the side like its objects (rendered, not
    # random silhouettes): more than a little overlap.
    assert both.side_iou["category_mean_shape"].mean() > 0.3
    for name, values in scores.items():
        assert values.shape == result.iou.shape and np.all((values >= 0) & (values <= 1)), name
    assert scores["oracle"].min() >= 0.97
    assert np.all(scores["oracle"] >= scores["mean_shape"])
    cid = result.categories[0][0]
    coarse = float(voxel_iou(oracle_voxels(root, cid, "test", 0, 0.6, 24), test.voxels(0)))
    assert coarse < scores["oracle"][0]
    shape = dataset_shape(root, cid, "test", 0)
    assert shape.sdf_numpy(np.zeros((1, 3))).shape == (1,)
    with pytest.raises(ValueError, match="no object 5"):
        dataset_shape(root, cid, "test", 5)


def test_baseline_names_are_checked():
    assert check_baselines(None) == () and check_baselines(["retrieval", "retrieval"]) == ("retrieval",)
    assert set(READS) == set(BASELINES) and READS["retrieval"] == "the input camera"
    assert READS["retrieval_any_view"] == "nothing"
    with pytest.raises(ValueError, match="unknown baseline 'nearest'"):
        check_baselines(["nearest"])
    with pytest.raises(ValueError, match="string"):
        check_baselines("retrieval")


def _fake(nmr: bool) -> EvaluationResult:
    cats = tuple(NMR_CATEGORIES[:2])
    return EvaluationResult(split="test", dataset="x", categories=cats, is_nmr_shapenet=nmr, checkpoint=None,
                            stage="joint", output="refined", category=np.array([0, 0, 1, 1]),
                            object_index=np.array([0, 1, 0, 1]), view=np.zeros(4, dtype=np.int64),
                            iou=np.array([0.6, 0.8, 0.5, 0.5]),
                            baselines={"mean_shape": np.array([0.2, 0.2, 0.1, 0.1]),
                                       "retrieval": np.array([0.5, 0.5, 0.6, 0.6])})


def test_baselines_are_rows_of_the_table_with_ours_minus_retrieval(tmp_path):
    res = _fake(nmr=False)
    header, rows = table_rows(res)
    by_method = {r[0]: r[1:] for r in rows}
    assert header == ["method", "airplane", "bench", "mean"]
    assert by_method["mean shape"] == ["0.2000", "0.1000", "0.1500"]
    assert by_method["retrieval"] == ["0.5000", "0.6000", "0.5500"]
    assert by_method["ours - retrieval"] == ["+0.2000", "-0.1000", "+0.0500"]
    assert not any("paper" in r[0] for r in rows)  # procedural data: no reference rows
    text = format_table(res)
    assert "not comparable" in text and "retrieval:" in text
    files = write_report(res, tmp_path)
    summary = json.loads(files["json"].read_text())
    assert summary["baselines"]["retrieval"]["mean"] == pytest.approx(0.55)
    assert summary["ours_minus_retrieval"]["categories"]["bench"] == pytest.approx(-0.1)
    assert "iou_retrieval" in files["per_image"].read_text().splitlines()[0]


def test_baselines_seen_from_the_side_are_rows_of_the_side_view_table(tmp_path):
    res = dataclasses.replace(_fake(nmr=False), side_iou=np.array([0.7, 0.9, 0.6, 0.8]),
                              baseline_side_iou={"retrieval": np.array([0.5, 0.7, 0.4, 0.4])})
    text = format_table(res)
    side = text[text.index("Side views:"):]
    assert "a retrieved training object shows its stored silhouettes" in side
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in side.splitlines() if line.startswith("| ")}
    assert rows["ours (refined)"] == ["0.8000", "0.7000", "0.7500"]
    assert rows["retrieval"] == ["0.6000", "0.4000", "0.5000"]
    files = write_report(res, tmp_path)
    summary = json.loads(files["json"].read_text())
    assert summary["side_views"]["mean"] == pytest.approx(0.75)
    assert summary["side_views"]["baselines"]["retrieval"]["mean"] == pytest.approx(0.5)
    assert summary["side_views"]["baselines"]["retrieval"]["categories"]["airplane"] == pytest.approx(0.6)
    assert "side_iou_retrieval" in files["per_image"].read_text().splitlines()[0]
    assert "side_iou_retrieval_mean" in files["per_object"].read_text().splitlines()[0]
    # Without baselines seen from the side, the side-view table is ours alone.
    plain = format_table(dataclasses.replace(res, baseline_side_iou={}))
    assert "stored silhouettes" not in plain and "| retrieval" in plain.split("Side views:")[0]
    assert "| retrieval" not in plain.split("Side views:")[1]


def test_notes_say_what_each_row_reads(tmp_path):
    res = dataclasses.replace(_fake(nmr=False), reads="nothing",
                              baselines={**_fake(nmr=False).baselines,
                                         "retrieval_any_view": np.array([0.4, 0.4, 0.5, 0.5])})
    text = format_table(res)
    note = next(line for line in text.splitlines() if line.startswith("- What each row reads"))
    for part in ("ours: nothing", "mean shape: nothing", "retrieval: the input camera",
                 "retrieval (any view): nothing"):
        assert part in note, part
    summary = json.loads(write_report(res, tmp_path)["json"].read_text())
    assert summary["reads"] == "nothing"
    assert summary["baselines"]["retrieval"]["reads"] == "the input camera"
    assert summary["baselines"]["retrieval_any_view"]["reads"] == "nothing"
    # What the model reads comes from its network and calibration.
    net = SimpleNamespace(needs_views=False)
    assert model_reads(LoadedModel(net)) == "nothing"
    assert model_reads(LoadedModel(net, calibration=Calibration(level=0.01))) == "nothing"
    assert model_reads(LoadedModel(net, calibration=Calibration(carve="view"))) == \
        "the input camera (its calibration's carving)"
    assert model_reads(LoadedModel(SimpleNamespace(needs_views=True))) == "the input camera (its pixel-aligned head)"
    assert model_reads(LoadedModel(SimpleNamespace(needs_views=True, prior=object()),
                                   calibration=Calibration(carve="view"))) == \
        "the input camera (its pixel-aligned head, its shape prior and its calibration's carving)"


def test_nmr_tables_give_both_sdfdiff_means():
    text = format_table(_fake(nmr=True))
    assert "0.6674" in text and "0.6784" in text
