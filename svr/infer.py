"""The inference command, ``python -m svr.infer ckpt_path=X.ckpt images=photo.png`` /
``sdfdiff-infer`` (configs/infer.yaml, whose comments show the command lines): a checkpoint's
reconstructions of images, per input ``<stem>`` its SDF grid (``<stem>_sdf.npz``: ``values`` (N, N, N)
float32 in renderer.SDFGrid's layout, ``bbox_min``/``bbox_max``, ``stage``, ``checkpoint``), its
watertight mesh (``<stem>.ply``, ``<stem>.obj``) and a preview (``<stem>_views.png``: the input beside
renders of the prediction), written into ``output_dir``, else hydra's run folder
``<paths.output_dir>/infer/<time>``. ``run`` loads the model (``svr.inference.prediction.load_model``)
and calls ``svr.inference.reconstruction.infer_files``. A mistake in the settings or files (an
unreadable image, a transparent one, an inverted mask) is one line ``sdfdiff-infer: error: ...`` with
exit status 2 (``sdfcommon.tooling.commands``)."""
from __future__ import annotations

from pathlib import Path

from hydra.core.hydra_config import HydraConfig

from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.outputs import ensure_output_dir
from svr.inference.prediction import load_model
from svr.inference.reconstruction import infer_files
from svr.inference.settings import InferSettings


def run(settings: InferSettings) -> list[dict[str, Path]]:
    """Reconstructs the images and prints what it wrote; returns per image {format: path}."""
    out = settings.output_dir or HydraConfig.get().runtime.output_dir
    folder = ensure_output_dir(out, "output_dir")
    model = load_model(settings.ckpt_path, settings.device)
    print(f"checkpoint {model.checkpoint} ({model.stage} stage, {model.output_name} output) on {model.device}")
    results = infer_files(model, settings.images, folder, masks=settings.masks, mask_suffix=settings.mask_suffix or "",
                          views=settings.views, render_size=settings.render_size, batch_size=settings.batch_size,
                          formats=settings.formats, require_watertight=settings.require_watertight,
                          backend=settings.backend, progress=settings.progress,
                          input_view=settings.input_view)
    for files in results:
        print("wrote " + ", ".join(str(p) for p in files.values()))
    print(f"{len(results)} image(s) -> {folder}")
    return results


main = hydra_entry("infer", run)


if __name__ == "__main__":
    main()


__all__ = ["run", "main"]
