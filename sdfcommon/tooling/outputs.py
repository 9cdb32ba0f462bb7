"""Atomic writes of output files (svr's and mvr's alike): every file goes to a temporary name beside
it, then ``os.replace`` puts it in place, so a run killed mid-write never leaves a truncated file."""
from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import re
import tempfile
import zipfile
from pathlib import Path
from typing import Callable, IO, Iterator, Sequence

import numpy as np


def _file_mode() -> int:
    """The mode a plainly created file gets (0o666 less the umask); mkstemp would give 0o600."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yields the name of an empty temporary file in ``path``'s folder (``.<name>.<8 chars>.tmp``) for
    code that writes by file name (e.g. ``numpy.lib.format.open_memmap``); when the block ends
    normally, gives it the mode a plainly created file gets and renames it to ``path``; when it
    raises, deletes it. The block must close what it opened on the file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _file_mode())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write(path: str | Path, write: Callable[[IO[bytes]], None]) -> Path:
    """Calls ``write(f)`` on a temporary binary file in ``path``'s folder, flushes it to disk, then
    renames it to ``path`` (``atomic_path``)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Writes UTF-8 text atomically."""
    return atomic_write(path, lambda f: f.write(text.encode("utf-8")))


def write_json(path: str | Path, data) -> Path:
    """Writes JSON atomically (non-finite floats become null, so the file is standard JSON)."""
    return write_text(path, json.dumps(_finite(data), indent=2, sort_keys=False) + "\n")


def _finite(x):
    if isinstance(x, float) and not np.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def write_csv(path: str | Path, rows: Sequence[dict], columns: Sequence[str]) -> Path:
    """Writes rows (dicts) as CSV with the given columns, atomically."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow(row)
    return write_text(path, buf.getvalue())


def write_torch(path: str | Path, obj) -> Path:
    """``torch.save`` atomically."""
    import torch  # heavy: this module stays light for the commands that write no tensors

    return atomic_write(path, lambda f: torch.save(obj, f))


# The date every member of a written npz carries (zip's earliest), so that the same arrays give the
# same bytes (``numpy.savez_compressed`` stamps the current time).
_NPZ_DATE = (1980, 1, 1, 0, 0, 0)


def write_npz(path: str | Path, **arrays) -> Path:
    """What ``numpy.savez_compressed`` writes (one deflated ``<key>.npy`` per array, read back by
    ``numpy.load``), atomically and reproducibly: the same arrays give the same bytes. Arrays are
    streamed, so a memory map is never read whole into memory."""

    def write(f: IO[bytes]) -> None:
        with zipfile.ZipFile(f, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
            for key, value in arrays.items():
                info = zipfile.ZipInfo(f"{key}.npy", date_time=_NPZ_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                with zf.open(info, mode="w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)

    return atomic_write(path, write)


def write_mesh(path: str | Path, mesh) -> Path:
    """Exports a trimesh.Trimesh atomically; the format comes from the suffix (.ply, .obj, ...)."""
    path = Path(path)
    kind = path.suffix.lstrip(".").lower()
    return atomic_write(path, lambda f: f.write(_as_bytes(mesh.export(file_type=kind))))


def _as_bytes(data) -> bytes:
    return data.encode("utf-8") if isinstance(data, str) else bytes(data)


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """Writes an (H, W) or (H, W, 3) float image in [0, 1] as an 8-bit PNG, atomically."""
    from PIL import Image  # heavy: only PNG writing needs it

    arr = (np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0) * 255).round().astype(np.uint8)
    return atomic_write(path, lambda f: Image.fromarray(arr).save(f, format="PNG"))


# The atomic writers' temporary names: "." + the target's name + "." + 8 random characters (mkstemp)
# + ".tmp"; 16 hex digits in place of the 8 characters are what svr's checkpoint writer left before
# it used ``atomic_write``.
_TEMPORARY = re.compile(r"^\..+\.[A-Za-z0-9_]{8,16}\.tmp$")


def remove_stale_temporaries(folder: str | Path) -> list[Path]:
    """Deletes the temporary files that atomic writes (``atomic_write``, ``atomic_path``) left
    in ``folder`` and its subfolders when a process was killed mid-write (SIGKILL gives no chance to
    clean up). Call it only where no other process is writing. Returns the files removed."""
    removed = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for path in folder.rglob(".*.tmp"):
        if path.is_file() and _TEMPORARY.match(path.name):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def ensure_output_dir(path: str | Path, argument: str = "output_dir") -> Path:
    """Creates an output folder if needed, checks that files can be written into it before any
    work, and removes the temporaries a run killed mid-write left in it (``remove_stale_temporaries``).

    Raises:
        ValueError naming ``argument`` and the folder when it cannot be created or written.
    """
    folder = Path(path).expanduser()
    try:
        make_writable_folder(folder)
    except OSError as err:
        raise ValueError(f"{argument}: cannot write to the folder {folder} ({err.strerror or err})") from None
    remove_stale_temporaries(folder)
    return folder


def make_writable_folder(folder: str | Path) -> None:
    """Creates ``folder`` (and its parents) if needed and writes and deletes a probe file in it.

    Raises:
        OSError when the folder cannot be created or written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fd, probe = tempfile.mkstemp(prefix=".write-test.", dir=folder)
    os.close(fd)
    os.unlink(probe)
