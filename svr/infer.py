"""The inference command, ``python -m svr.infer ckpt_path=X.ckpt images=photo.png`` /
``sdfdiff-infer`` (configs/infer.yaml, whose comments show the command lines): a checkpoint's
reconstructions of images, per input ``<stem>`` its SDF grid (``<stem>_sdf.npz``: ``values`` (N, N, N)
float32 in renderer.SDFGrid's layout, ``bbox_min``/``bbox_max``, ``stage``, ``checkpoint``), its
marching-cubes mesh (``<stem>.ply``, ``<stem>.obj``; checked for watertightness, a mesh that is not
is reported) and a preview (``<stem>_views.png``: the input beside renders of the prediction),
written into ``output_dir``, else hydra's run folder ``<paths.output_dir>/infer/<time>``; a folder
that already holds files is refused unless ``overwrite=true``. ``run`` loads the model
(``svr.inference.prediction.load_model``) and calls ``svr.inference.reconstruction.infer_files``,
which goes on past an image that fails (unreadable, refused, no surface); the command lists each
image's files or failure and what the folders held that was not read, and ends with one line
``sdfdiff-infer: error: ...`` and exit status 2 when any image failed, as for a mistake in the
settings (``sdfcommon.tooling.commands``)."""
from __future__ import annotations

from pathlib import Path

from hydra.core.hydra_config import HydraConfig

from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.outputs import ensure_output_dir
from svr.inference.prediction import load_model
from svr.inference.reconstruction import ImageResult, InferenceReport, infer_files
from svr.inference.settings import InferSettings


def run(settings: InferSettings) -> InferenceReport:
    """Reconstructs the images and prints what it wrote, what failed and what it skipped.

    Raises:
        ValueError when the output folder already holds files (without ``overwrite``), or after
        the run when an image failed (the other images' files are written).
    """
    key = "output_dir" if settings.output_dir else "hydra.run.dir"
    folder = ensure_output_dir(settings.output_dir or HydraConfig.get().runtime.output_dir, key)
    held = _held_files(folder)
    if held and not settings.overwrite:
        raise ValueError(f"{key}: {folder} already holds files ({', '.join(held[:3])}{', ...' if len(held) > 3 else ''})"
                         f"; give a new or empty folder, or overwrite=true to write into it (same names are replaced)")
    model = load_model(settings.ckpt_path, settings.device)
    print(f"checkpoint {model.checkpoint} ({model.stage} stage, {model.output_name} output) on {model.device}")
    report = infer_files(model, settings.images, folder, masks=settings.masks, mask_suffix=settings.mask_suffix or "",
                         views=settings.views, render_size=settings.render_size, batch_size=settings.batch_size,
                         formats=settings.formats, require_watertight=settings.require_watertight,
                         backend=settings.backend, progress=settings.progress, input_view=settings.input_view,
                         azimuth=settings.azimuth, frame=settings.frame, elevation=settings.elevation)
    for item in report.images:
        if item.done:
            notes = ([item.camera] if item.camera else []) + ([item.problem] if item.problem else [])
            note = f" ({'; '.join(notes)})" if notes else ""
            print("wrote " + ", ".join(str(p) for p in item.files.values()) + note)
        else:
            print(f"failed: {_named(item)}")
    if report.skipped:
        print(f"skipped {len(report.skipped)} file(s) or folder(s) that are not PNG/JPEG images: "
              + ", ".join(str(p) for p in report.skipped))
    failed = report.failed
    print(f"{len(report.done)} of {len(report.images)} image(s) done, {len(failed)} failed -> {folder}")
    if len(failed) == 1:
        raise ValueError(f"1 of {len(report.images)} image(s) failed: {_named(failed[0])}")
    if failed:
        raise ValueError(f"{len(failed)} of {len(report.images)} image(s) failed (listed above): "
                         + ", ".join(str(r.image) for r in failed))
    return report


def _named(item: ImageResult) -> str:
    """An ImageResult's failure, naming its image once."""
    return item.error if str(item.image) in item.error else f"{item.image}: {item.error}"


def _held_files(folder: Path) -> list[str]:
    """The names in a run folder that are not a run's own records (hidden entries such as
    ``.hydra/``, hydra's ``*.log``): results or other files a run would mix its files into."""
    return sorted(p.name for p in folder.iterdir()
                  if not p.name.startswith(".") and not (p.is_file() and p.suffix == ".log"))


main = hydra_entry("infer", run)


if __name__ == "__main__":
    main()


__all__ = ["run", "main"]
