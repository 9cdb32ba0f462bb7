"""The typed settings of the inference command (configs/infer.yaml), built from the composed config
by ``sdfcommon.tooling.settings.build_settings``: an unknown key, a value of the wrong type or one
out of range fails with a message naming the key before the command makes its folder. Every
default is written once, in the YAML."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.hardware import check_backend
from sdfcommon.tooling.settings import PathSettings
from svr.inference.input_camera import check_elevation, view_of_azimuth
from svr.inference.prediction import check_input_views
from svr.inference.reconstruction import check_formats
from svr.nmr.format import check_view_ids

# The previews of a batch are rendered at once (batch_size x views x render_size^2 rays): a bound
# on their memory, and 8x the network's 64^2 input side.
MAX_RENDER_SIZE = 512


@dataclass(frozen=True)
class InferSettings:
    """The inference command's settings (configs/infer.yaml; its comments say more).

    Attributes:
        ckpt_path: the checkpoint whose network reconstructs the images.
        images: an image, a folder (every PNG/JPEG in it) or a list of them.
        masks: one mask file per image (None: ``<stem><mask_suffix>.*`` beside the image if any).
        mask_suffix: files named like this are masks, not inputs (None or "": no masks are looked for).
        output_dir: where the files go; None: hydra's run folder (``<paths.output_dir>/infer/<time>``).
        device: "auto", "cpu", "cuda" or "cuda:N".
        batch_size: images per forward pass. views: NMR views of the preview renders (may be empty).
        render_size: side of the preview renders (at most ``MAX_RENDER_SIZE``). formats: among npz,
            ply, obj, png.
        require_watertight: a mesh that is not watertight is an error rather than a warning.
        backend: the renderer's march (one that can run here). progress: a progress bar.
        paths: as ``PathSettings``.
        input_view: the NMR view index the images were taken from, in [0, 24) (None: estimated by
            the checkpoint's camera head where it has one).
        azimuth: the same camera's azimuth in degrees (not both).
        elevation: the camera's elevation in degrees (None: 30 for a given camera, else the camera
            head's estimate where it has one).
        frame: crop and scale each photo as the training renders are framed (None: where the
            camera is not given).
        overwrite: write into an output folder that already holds files (same names are replaced);
            False: such a folder is refused.
    """

    ckpt_path: str
    images: Union[str, list[str]]
    masks: Optional[list[Optional[str]]]
    mask_suffix: Optional[str]
    output_dir: Optional[str]
    device: str
    batch_size: int
    views: list[int]
    render_size: int
    formats: list[str]
    require_watertight: bool
    backend: str
    progress: bool
    input_view: Optional[float]
    azimuth: Optional[float]
    elevation: Optional[float]
    frame: Optional[bool]
    overwrite: bool
    paths: PathSettings

    def __post_init__(self) -> None:
        check_int(self.batch_size, "batch_size", 1)
        check_view_ids(self.views, "views")
        check_int(self.render_size, "render_size", 1)
        if self.render_size > MAX_RENDER_SIZE:
            raise ValueError(f"render_size must be at most {MAX_RENDER_SIZE} (the previews of a batch are "
                             f"rendered at once), got {self.render_size!r}")
        check_formats(self.formats)
        check_backend(self.backend)
        check_input_views(self.input_view, 1, False, "input_view")
        if self.input_view is not None and self.azimuth is not None:
            raise ValueError("give input_view or azimuth, not both")
        if self.azimuth is not None:
            view_of_azimuth(self.azimuth)
        check_elevation(self.elevation)


__all__ = ["InferSettings", "MAX_RENDER_SIZE"]
