"""benchmarks.mvr_accuracy_shapes at toy size: a shape reconstructed in this process with the
command's settings, its row and views in the report, and a finished run reused."""
from __future__ import annotations

import benchmarks.mvr_accuracy_shapes as module
from benchmarks.accuracy_vs_time_mvr import QUICK


def test_toy_run_writes_the_table_and_reuses_the_run(tmp_path, monkeypatch):
    import mvr

    runtimes = []
    monkeypatch.setattr(mvr, "configure_runtime", lambda **kwargs: runtimes.append(kwargs))  # process-wide
    work, docs = tmp_path / "work", tmp_path / "docs"
    argv = ["torus", "--work", str(work), "--docs", str(docs), "--extra", *QUICK]
    module.main(argv)
    text = (docs / "mvr_shapes.md").read_text()
    assert "| torus | " in text and "0.015637" in text and "failed" not in text
    assert (work / "torus" / "metrics.json").is_file()
    assert (docs / "mvr_views_torus.png").stat().st_size > 1000 and runtimes == [{"threads": 1}]

    def no_rerun(*args, **kwargs):
        raise AssertionError("a finished run must be reused")

    monkeypatch.setattr(module, "reconstruct_with_overrides", no_rerun)
    module.main(argv)
    def errors(md):  # the row's hausdorff_rel and chamfer_rel (the load average may differ)
        return [line.split("|")[2:4] for line in md.splitlines() if line.startswith("| torus |")]

    assert errors((docs / "mvr_shapes.md").read_text()) == errors(text)
