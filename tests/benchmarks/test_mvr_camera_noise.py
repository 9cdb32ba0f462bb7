"""benchmarks.mvr_camera_noise's table: each noisy run's Hausdorff distance over the noiseless run's
of the same mesh and seed, in bold where a refined run meets issue 42's criterion."""
from __future__ import annotations

from benchmarks.mvr_camera_noise import CRITERION, RUNS, table


def _row(mesh: str, seed: int, run: str, hausdorff: float) -> dict:
    metrics = {"hausdorff_rel": hausdorff, "chamfer_rel": 0.001, "mesh_genus": 0, "target_genus": 0, "seconds": 10}
    if run != "noiseless":
        metrics.update(camera_reprojection_px_given=0.6, camera_reprojection_px_final=0.3)
    return {"mesh": mesh, "seed": seed, "run": run, "metrics": metrics}


def test_table_gives_the_ratio_to_the_noiseless_run_and_marks_the_criterion():
    assert list(RUNS)[0] == "noiseless" and all("camera_rounds" not in o for o in RUNS["noise, cameras refined"])
    rows = [_row("bunny", 0, "noiseless", 0.010), _row("bunny", 0, "camera noise", 0.030),
            _row("bunny", 0, "noise, cameras refined", 0.010 * CRITERION * 1.01),
            _row("bunny", 0, "noise, cameras refined, 2 rounds", 0.012),
            _row("bunny", 1, "noiseless", 0.020), _row("bunny", 1, "noise, cameras refined", 0.020)]
    lines = table(rows).splitlines()[2:]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    assert [c[4] for c in cells] == ["", "3.00", "1.26", "**1.20**", "", "**1.00**"]
    assert cells[1][7:9] == ["0.600", "0.300"] and cells[0][7:9] == ["", ""]
