"""svr.nmr.format: which folders are real NMR ShapeNet (the paper's rows apply only there)."""
from __future__ import annotations

import json

from svr.nmr.format import NMR_CATEGORIES, is_nmr_shapenet


def test_only_a_folder_without_metadata_and_with_the_benchmark_ids_is_nmr_shapenet(tmp_path):
    ids = [cid for cid, _ in NMR_CATEGORIES[:3]]
    assert is_nmr_shapenet(tmp_path, ids)
    assert not is_nmr_shapenet(tmp_path, [*ids, "12345678"])  # a category of the user's own
    assert not is_nmr_shapenet(tmp_path, [])
    # The mesh builder (and the procedural generator) write metadata.json, with the same ids where
    # the categories match: such data is NMR-format, not NMR ShapeNet.
    (tmp_path / "metadata.json").write_text(json.dumps({"builder_version": 2}))
    assert not is_nmr_shapenet(tmp_path, ids)
