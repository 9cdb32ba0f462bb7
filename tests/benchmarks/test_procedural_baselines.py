"""benchmarks.procedural_baselines at toy size: every baseline per category, the oracle on top."""
from __future__ import annotations

from benchmarks.procedural_baselines import baseline_table, main


def test_toy_baseline_table(tmp_path):
    toy = ["data.categories=[chair,lamp]", "data.train=2", "data.val=1", "data.test=1", "data.supersample=1",
           "data.generation_workers=0"]
    table, summary = baseline_table("demo", "test", tmp_path / "cache", toy, progress=False)
    assert list(summary) == ["mean_shape", "category_mean_shape", "retrieval", "oracle"]
    assert "| chair | lamp | mean |" in table and "2 objects x 24 views = 48 images" in table
    for row in summary.values():
        assert set(row["categories"]) == {"chair", "lamp"} and 0.0 <= row["mean"] <= 1.0
    assert summary["oracle"]["mean"] >= 0.97 and summary["oracle"]["mean"] > summary["mean_shape"]["mean"]


def test_command_writes_the_report(tmp_path, monkeypatch):
    import benchmarks.procedural_baselines as module

    monkeypatch.setattr(module, "baseline_table", lambda *a, **k: ("| baseline |\n", {}))
    out = tmp_path / "report.md"
    assert main(["--preset", "demo", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("# Procedural benchmark: baselines") and "--preset demo --split test" in text
