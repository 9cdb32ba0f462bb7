"""The hydra config composes and instantiates into the plain objects reconstruct() takes."""
from __future__ import annotations

import dataclasses

import pytest
import torch
from hydra.errors import ConfigCompositionException

from mvr import (GridSettings, NoiseSettings, OptimSettings, RigSettings, Schedule, ScoringSettings,
                 TargetSettings)
from mvr.settings import MVRSettings, RuntimeSettings, compose_config, reconstruct_kwargs
from mvr.reconstruct import default_scene
from renderer import Scene, TraceSettings
from sdfcommon.tooling.settings import PathSettings, build_settings

# The head light without falloff of mvr/preset=paper (issue 4's settings).
PAPER_SCENE = Scene(effects=("silhouette", "shading"), lights=(), camera_light=0.8, camera_light_falloff=False,
                    ambient=0.2, albedo=(1.0,), background=0.0)


def test_defaults_instantiate():
    kw = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused"]))
    expected = {"rig": RigSettings, "grid": GridSettings, "target_settings": TargetSettings,
                "schedule": Schedule, "optim": OptimSettings, "noise": NoiseSettings,
                "evaluation": ScoringSettings, "scene": Scene, "trace": TraceSettings}
    for key, cls in expected.items():
        assert isinstance(kw[key], cls), key
    assert kw["schedule"].grid_resolutions() == [8, 16, 32, 64]  # paper: 8^3 up to 64^3
    assert kw["optim"].hard_view_updates == 20 and kw["optim"].easy_view_updates == 5  # paper
    # The YAML and the dataclasses agree, so library users get the command's defaults.
    for key, cls in expected.items():
        if key != "scene":
            assert kw[key] == cls(), key
    assert kw["scene"] == default_scene()
    assert kw["scene"].wants("shading") and kw["scene"].wants("silhouette")


@pytest.mark.parametrize("group, image_std, camera_std", [("image", 0.1732, 0.0), ("camera", 0.0, 0.05)])
def test_noise_group(group, image_std, camera_std):
    kw = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused", f"mvr/noise={group}"]))
    assert kw["noise"] == NoiseSettings(image_std=image_std, camera_std=camera_std)


def test_overrides_and_bad_values():
    kw = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused", "schedule.levels=8",
                                            "optim.max_passes=[3,2]", "schedule.image_size=64"]))
    assert len(kw["schedule"].grid_resolutions()) == 8 and kw["schedule"].image_size == 64
    assert kw["optim"].for_level("max_passes", 5) == 2
    with pytest.raises(Exception, match="lr"):
        reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused", "optim.lr=-1"]))
    with pytest.raises(ConfigCompositionException):
        compose_config(["target=torus", "mvr/noise=loud"])


def test_configure_runtime_starts_the_renderers_thread_pool():
    """configure_runtime sets numba's thread count, which starts numba's pool: in a fresh process
    it must be the pool the renderer's kernels choose (renderer.start_cpu_thread_pool: "omp",
    torch's own OpenMP runtime, where numba has that layer), not numba's own default choice."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = ("import json, numba\nfrom mvr import configure_runtime\nconfigure_runtime(threads=2)\n"
            "print(json.dumps(numba.threading_layer()))\n")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "NUMBA_DISABLE_JIT")}
    out = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[2], env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == "omp"


def test_paper_preset_restores_the_papers_settings():
    """mvr/preset=paper is the baseline the real-scan benchmark measures beside the defaults."""
    paper = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused", "mvr/preset=paper"]))
    assert paper["trace"] == TraceSettings(threshold_scale=0.5, inner_depth=8.0)
    assert paper["schedule"].grid_resolutions() == [8, 16, 32, 64]
    assert paper["scene"] == PAPER_SCENE
    assert paper["optim"].erosion == 0.0 and not paper["optim"].carve and paper["optim"].carve_rounds() == 0
    # A command-line override still wins over the preset.
    over = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused", "mvr/preset=paper",
                                              "trace.threshold_scale=0.3"]))
    assert over["trace"].threshold_scale == 0.3


def test_fine_preset_is_the_defaults_with_a_finer_last_level():
    """... and the plain squared silhouette difference it was measured with (no dead zone), no
    erosion of the last level and no residual carve; the defaults carve once."""
    fine = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused", "mvr/preset=fine"]))
    default = reconstruct_kwargs(compose_config(["target=torus", "out_dir=unused"]))
    assert fine["schedule"].grid_resolutions() == [8, 16, 32, 48, 96]
    assert default["schedule"].grid_resolutions() == [8, 16, 32, 64]
    assert default["optim"].silhouette_tolerance == 0.27 and fine["optim"].silhouette_tolerance == 0.0
    assert default["optim"].erosion == 2.0 and fine["optim"].erosion == 0.0
    assert default["optim"].carve_rounds() == 1 and fine["optim"].carve_rounds() == 0
    assert fine["optim"] == dataclasses.replace(default["optim"], silhouette_tolerance=0.0, erosion=0.0,
                                                residual_carve=0.0)
    rest = ("schedule", "optim")
    assert {k: v for k, v in fine.items() if k not in rest} == {k: v for k, v in default.items() if k not in rest}


def test_threads_default_to_every_core():
    from mvr.runtime import available_cores, configure_runtime

    assert compose_config(["target=torus"]).runtime.threads is None
    assert available_cores() >= 1
    before = torch.get_num_threads()
    try:
        assert configure_runtime(threads=None, tune_malloc=False, flush_denormal=False)["threads"] == available_cores()
        assert torch.get_num_threads() == available_cores()
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ValueError, match="threads"):
        configure_runtime(threads=0)


def test_settings_are_built_from_mvr_yaml():
    """configs/mvr.yaml becomes one MVRSettings; reconstruct_kwargs takes it or the composed config."""
    settings = build_settings(compose_config(["target=torus"]))
    assert isinstance(settings, MVRSettings) and isinstance(settings.paths, PathSettings)
    assert settings.runtime == RuntimeSettings(threads=None, tune_malloc=True, flush_denormal=True)
    assert settings.out_dir.startswith(f"{settings.paths.output_dir}/mvr/")
    moved = build_settings(compose_config(["target=torus", "paths.output_dir=/elsewhere"]))
    assert moved.out_dir.startswith("/elsewhere/mvr/")
    assert reconstruct_kwargs(settings) == reconstruct_kwargs(compose_config(["target=torus"]))
    assert isinstance(settings.optim, OptimSettings) and isinstance(settings.scene, Scene)
    with pytest.raises(ValueError, match="nonsense: unknown setting"):
        build_settings(compose_config(["target=torus", "+nonsense=1"]))
    with pytest.raises(ValueError, match="optim.nope: unknown setting"):
        build_settings(compose_config(["target=torus", "+optim.nope=1"]))
    with pytest.raises(TypeError, match="runtime.tune_malloc must be"):
        build_settings(compose_config(["target=torus", "runtime.tune_malloc=often"]))
    with pytest.raises(ValueError, match="runtime.threads must be an integer >= 1"):
        build_settings(compose_config(["target=torus", "runtime.threads=0"]))
