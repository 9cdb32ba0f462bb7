"""Input images for inference, read like the datasets' and checked: RGBA (alpha = the object's
silhouette), or RGB/grey with a mask file or on a plain background (removed); folders and glob patterns expanded (``find_images``, which
also says what it left out); a silhouette that cannot be an object on a background refused
(``check_silhouette``).
"""
from __future__ import annotations

import glob
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
import torch

from svr.inference.framing import border_pixels, object_rgba
from svr.nmr.format import images_to_float

PathLike = Union[str, os.PathLike]
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
# The largest share of the image border a silhouette may cover: more is an inverted mask (see
# check_silhouette); an object cropped tightly at one or two edges stays well below it.
MAX_BORDER_COVER = 0.5
GLOB_CHARACTERS = "*?["


def _open_image(path: Path, what: str):
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        img = Image.open(path)
        img.load()
    except Image.DecompressionBombError:
        raise ValueError(f"{path}: the {what} is too large to read safely (more than twice PIL's "
                         f"Image.MAX_IMAGE_PIXELS = {Image.MAX_IMAGE_PIXELS} pixels); shrink it first") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
        raise ValueError(f"{path}: cannot read the {what} ({err})") from None
    return img


def check_silhouette(alpha: np.ndarray, name: str) -> None:
    """Refuses a silhouette that cannot be an object on a background: empty (no pixel opaque: a
    fully transparent image or a black mask) or covering more than half of the image's border (an
    inverted mask: object transparent, background opaque, whether or not the object touches an
    edge; an object of the benchmark's framing lies inside the frame with background all round).
    Opaque: alpha >= 128 of 255.

    Args:
        alpha: (H, W) uint8 alpha channel or mask (255 = object).
    Raises:
        ValueError naming ``name`` and saying which.
    """
    opaque = np.asarray(alpha) >= 128
    if not opaque.any():
        raise ValueError(f"{name}: the silhouette is empty (no opaque pixel: a fully transparent image or a "
                         f"black mask); the object must be opaque (alpha or mask white) on a transparent background")
    border = border_pixels(opaque)
    covered = float(border.mean())
    if covered > MAX_BORDER_COVER:
        raise ValueError(f"{name}: the silhouette covers {covered:.0%} of the image border (at most "
                         f"{MAX_BORDER_COVER:.0%} allowed), so the mask looks inverted (object transparent, background "
                         f"opaque); the object must be opaque (alpha or mask white) with transparent background "
                         f"(black in a mask) around it; a tight crop needs padding")


def _has_alpha(img) -> bool:
    return img.mode in ("RGBA", "LA", "PA", "La", "RGBa") or (img.mode == "P" and "transparency" in img.info)


def read_rgba(path: PathLike, mask: Optional[PathLike] = None) -> np.ndarray:
    """Reads one input image as it is, with its silhouette in the alpha channel.

    RGBA (or grey + alpha, or a palette with transparency) is used as is; for RGB or grey a mask
    file (any mode, read as grey: white = object) replaces the alpha channel, and without one a plain
    background is removed (``svr.inference.framing.background_mask``; refused where the border is
    not one plain colour or nothing differs from it). The silhouette must be an object on a
    background (``check_silhouette``): a fully transparent image or an inverted mask is refused.

    Returns:
        (H, W, 4) uint8 RGBA, the file's size.
    Raises:
        FileNotFoundError / ValueError naming the image or mask file.
    """
    from PIL import Image

    path = Path(path)
    img = _open_image(path, "image")
    if mask is not None:
        mpath = Path(mask)
        m = _open_image(mpath, "mask").convert("L")
        if m.size != img.size:
            raise ValueError(f"{mpath}: mask size {m.size} differs from the image {path} size {img.size}")
        rgba = img.convert("RGB").convert("RGBA")
        rgba.putalpha(m)
    elif _has_alpha(img):
        rgba = img.convert("RGBA")
    else:  # a photo on a plain background: the background removed (or a one-line refusal)
        rgba = Image.fromarray(object_rgba(np.asarray(img.convert("RGB")), str(path)), "RGBA")
    check_silhouette(np.asarray(rgba.getchannel("A")), str(mask if mask is not None else path))
    return np.asarray(rgba, dtype=np.uint8)


def rgba_to_input(rgba: np.ndarray, name: str, image_size: int = 64) -> torch.Tensor:
    """An (H, W, 4) uint8 image as the network's input: a non-square image padded to a square
    (transparent, white), any other size resized to ``image_size`` (area averaging when shrinking)
    with a warning naming ``name``, then converted like the datasets' images
    (``svr.nmr.format.images_to_float``: RGB on white).

    Returns:
        (4, S, S) float32 RGBA in [0, 1].
    """
    from PIL import Image

    rgba = Image.fromarray(np.asarray(rgba, dtype=np.uint8), "RGBA")
    w, h = rgba.size
    if (w, h) != (image_size, image_size):
        warnings.warn(f"{name}: {w}x{h} image resized to {image_size}x{image_size}"
                      + (" (padded to a square first)" if w != h else ""), UserWarning, stacklevel=2)
        if w != h:
            side = max(w, h)
            square = Image.new("RGBA", (side, side), (255, 255, 255, 0))
            square.paste(rgba, ((side - w) // 2, (side - h) // 2))
            rgba = square
        resample = Image.Resampling.BOX if rgba.size[0] > image_size else Image.Resampling.BILINEAR
        rgba = rgba.resize((image_size, image_size), resample)
    arr = np.asarray(rgba, dtype=np.uint8).transpose(2, 0, 1)  # (4, S, S), row 0 = top
    return images_to_float(arr, "composite")


def load_image(path: PathLike, mask: Optional[PathLike] = None, image_size: int = 64) -> torch.Tensor:
    """Reads one input image for the network as it comes (``read_rgba``, then ``rgba_to_input``:
    resized, not framed; ``svr.inference.framing.frame_image`` frames).

    Returns:
        (4, S, S) float32 RGBA in [0, 1].
    Raises:
        FileNotFoundError / ValueError naming the image or mask file.
    """
    return rgba_to_input(read_rgba(path, mask), str(path), image_size)


@dataclass(frozen=True)
class ImageInputs:
    """The input images a list of paths, folders and patterns expands to.

    Attributes:
        images: the image files, in the order given (a folder's and a pattern's sorted).
        skipped: what a folder or a pattern held that is not read: files that are not PNG/JPEG
            and sub-folders (hidden names and masks are not listed).
    """

    images: tuple[Path, ...]
    skipped: tuple[Path, ...] = ()


def find_images(inputs: Union[PathLike, Sequence[PathLike]], mask_suffix: str = "_mask") -> ImageInputs:
    """Expands image paths, folders and glob patterns (``photos/*.png``, for a shell that passed
    the pattern on): a folder gives every PNG/JPEG in it (not its sub-folders), sorted, a pattern
    every PNG/JPEG it matches, except masks (files whose stem ends with ``mask_suffix``); their other
    entries are returned as ``skipped``. A file named itself is read whatever its suffix.

    Raises:
        ValueError when nothing is given, or a folder or pattern yields no image; FileNotFoundError
        naming a missing path or a pattern that matches nothing.
    """
    items = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs or [])
    if not items:
        raise ValueError("images must name at least one image file or folder")
    images: list[Path] = []
    skipped: list[Path] = []
    for item in items:
        p = Path(item).expanduser()
        if p.is_dir():
            entries, where = sorted(p.iterdir()), f"the folder {p}"
        elif p.exists():
            images.append(p)
            continue
        elif any(c in str(p) for c in GLOB_CHARACTERS):
            entries, where = sorted(Path(m) for m in glob.glob(str(p))), f"the pattern {p}"
            if not entries:
                raise FileNotFoundError(f"images: no file matches the pattern {p}")
        else:
            raise FileNotFoundError(f"image not found: {p}")
        readable = [f for f in entries if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES]
        found = [f for f in readable if not (mask_suffix and f.stem.endswith(mask_suffix))]
        if not found:
            raise ValueError(f"images: no PNG/JPEG image in {where}")
        images.extend(found)
        skipped.extend(f for f in entries if f not in readable and not f.name.startswith("."))
    return ImageInputs(images=tuple(images), skipped=tuple(skipped))


def find_mask(image: Path, mask_suffix: str = "_mask") -> Optional[Path]:
    """``<stem><mask_suffix>.<ext>`` beside the image (PNG/JPEG), if there is one."""
    if not mask_suffix:
        return None
    for ext in (image.suffix, *IMAGE_SUFFIXES):
        cand = image.with_name(f"{image.stem}{mask_suffix}{ext}")
        if cand.is_file():
            return cand
    return None


__all__ = ["load_image", "read_rgba", "rgba_to_input", "find_images", "ImageInputs", "find_mask", "check_silhouette", "IMAGE_SUFFIXES",
           "MAX_BORDER_COVER"]
