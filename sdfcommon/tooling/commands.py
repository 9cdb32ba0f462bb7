"""The one shape of every hydra entry point, and its one error handling.

An entry point is a function that takes the composed config and does the work, and a ``main()``
that is the hydra wrapper (as the lightning-hydra-template's ``train.py``)::

    def run(cfg: DictConfig) -> Result: ...
    main = hydra_entry("sdfdiff-infer", "infer", run)      # console script and ``python -m``

``main()`` runs ``run(cfg)`` inside ``hydra.main`` and:

* turns a user's mistake into ONE line on stderr, ``<prog>: error: <message>``, and exit status
  ``USAGE_ERROR`` (2, as argparse): ValueError, TypeError, OSError (missing, unreadable or
  unwritable files and folders), omegaconf's missing/invalid/unknown keys, a hydra instantiation
  whose cause is one of those (the cause's message, named by the config key), PIL's
  decompression-bomb error. Messages that wrap a ``torch.load`` failure lose torch's advice to load
  with ``weights_only=False``. Anything else (a bug) keeps its traceback (hydra's, exit status 1).
  ``SystemExit`` passes untouched (e.g. 143 after SIGTERM), as do KeyboardInterrupt and other
  BaseExceptions.
* leaves nothing of a failed run behind: when the run wrote nothing but its records (hydra's
  ``.hydra/`` folder, ``*.log`` files, and ``records``: ``config.yaml`` and ``settings.json`` by
  default, ``RUN_RECORDS``), those it created are deleted, those that existed before are restored
  to their bytes (a log is cut back to its length), and the run folder goes if the run created it
  and it is empty, with the empty folders made to hold it. What existed
  before the command started is never deleted: a snapshot of the run folder is taken by
  ``RunFolderGuard``, a hydra callback that ``main()`` adds, before hydra creates anything. A
  failed run that wrote results (e.g. checkpoints) keeps its folder as it is. A run that succeeds
  loses only its empty log files. Under ``-m`` (multirun) no snapshot is taken, so nothing is
  cleaned.
* checks, before hydra writes anything, that the run folder can be created and written (one line
  naming it otherwise).

Config getters that name the key and say what was expected: ``config_int(cfg, "batch_size",
minimum=1)`` -> "batch_size must be an integer >= 1, got 'abc'"; ``config_float``, ``config_choice``,
``config_ints``, ``config_object`` (instantiate a ``_target_`` node after checking its values
against the dataclass's field types).

The resolver ``${first_set:a,b,...}`` (registered on import) gives its first argument that is not
null or empty: ``hydra.run.dir: ${first_set:${output_dir},outputs/infer/${now:...}}`` makes the
run folder the output folder when one is given. ``${config_options:data}`` lists a config group's
options (for an entry's own ``hydra.help.template``, which then names only the groups it uses).
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Optional, Sequence

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf
from omegaconf import errors as oc_errors

from sdfcommon.tooling.checks import check_field_types, check_float, check_int
from sdfcommon.tooling.outputs import atomic_write, make_writable_folder
from sdfcommon.tooling.serialization import scrub_unsafe_advice

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
USAGE_ERROR = 2
# Files a run writes about itself (not results): cleaned after a failed run that wrote nothing else.
RUN_RECORDS = ("config.yaml", "settings.json")
_RECORD_BYTES = 1 << 20  # records above this are not restored (a config or settings file is a few KiB)


class UserError(ValueError):
    """A mistake in a command's settings or files; ``main()`` reports it in one line."""


def fail(message: str) -> None:
    """Raises ``UserError(message)``: the command stops with ``<prog>: error: <message>``."""
    raise UserError(message)


# ------------------------------------------------------------------------------------------------
# Which errors are a user's, and their one line


def _user_error_types() -> tuple[type, ...]:
    types: list[type] = [ValueError, TypeError, OSError, oc_errors.MissingMandatoryValue,
                         oc_errors.ValidationError, oc_errors.ConfigKeyError, oc_errors.ConfigAttributeError,
                         oc_errors.InterpolationResolutionError]
    try:
        from PIL import Image

        types.append(Image.DecompressionBombError)
    except ImportError:
        pass
    return tuple(types)


def user_message(err: BaseException) -> Optional[str]:
    """The one-line message of a user's mistake, or None when ``err`` is not one (a bug).

    A hydra ``InstantiationException`` is judged by its cause (``raise ... from``) and named by its
    config key; one without a cause (a ``_target_`` that cannot be found) is a user's mistake.
    """
    from hydra.errors import InstantiationException

    if isinstance(err, InstantiationException):
        cause = err.__cause__
        key = _full_key(err)
        if cause is None or isinstance(cause, (ImportError, AttributeError)):
            return _one_line(str(err), key)
        inner = user_message(cause)
        if inner is None:
            return None
        return inner if not key or inner.startswith(key) else f"{key}: {inner}"
    if not isinstance(err, _user_error_types()):
        return None
    if isinstance(err, oc_errors.OmegaConfBaseException):
        return _one_line(str(getattr(err, "msg", None) or err), _full_key(err))
    if isinstance(err, OSError) and err.filename is not None and str(err.filename) not in str(err.strerror):
        return _one_line(f"{err.filename}: {err.strerror or err}")
    return _one_line(str(err))


def _full_key(err: BaseException) -> str:
    key = getattr(err, "full_key", None)
    if key:
        return str(key)
    # hydra's InstantiationException keeps the key in its text: "...\nfull_key: optim"
    for line in str(err).splitlines():
        if line.strip().startswith("full_key:"):
            return line.split(":", 1)[1].strip()
    return ""


def _one_line(text: str, key: str = "") -> str:
    text = scrub_unsafe_advice(text)
    lines = [s.strip() for s in text.splitlines() if s.strip() and not s.strip().startswith(
        ("full_key:", "object_type=", "reference_type="))]
    line = " ".join(lines) if len(lines) <= 3 else lines[0]
    if key and key not in line:
        line = f"{key}: {line}"
    return line or "(no message)"


# ------------------------------------------------------------------------------------------------
# The run folder: a snapshot before hydra writes, the clean-up after a failure


@dataclass
class RunFolderSnapshot:
    """What a run folder held before the command: files (relative path -> size), the bytes of its
    records (to restore them) and its folders. ``existed`` False: the folder was not there;
    ``first_missing``: then the outermost of its folders that was not there either."""

    folder: Path
    existed: bool
    sizes: dict[str, int] = field(default_factory=dict)
    record_bytes: dict[str, bytes] = field(default_factory=dict)
    folders: set[str] = field(default_factory=set)
    output_subdir: Optional[str] = ".hydra"
    records: tuple[str, ...] = RUN_RECORDS
    first_missing: Optional[Path] = None

    @classmethod
    def take(cls, folder: Path, output_subdir: Optional[str] = ".hydra",
             records: tuple[str, ...] = RUN_RECORDS) -> "RunFolderSnapshot":
        snap = cls(folder=folder, existed=folder.is_dir(), output_subdir=output_subdir, records=tuple(records))
        if not snap.existed:
            snap.first_missing = folder
            while not snap.first_missing.parent.exists() and snap.first_missing.parent != snap.first_missing:
                snap.first_missing = snap.first_missing.parent
        if snap.existed:
            for rel, path in _walk(folder, snap.folders):
                snap.sizes[rel] = path.stat().st_size
                if snap.is_record(rel) and not rel.endswith(".log") and snap.sizes[rel] <= _RECORD_BYTES:
                    snap.record_bytes[rel] = path.read_bytes()
        return snap

    def is_record(self, rel: str) -> bool:
        """Whether a file (path relative to the folder) is one of the run's records about itself."""
        parts = Path(rel).parts
        if self.output_subdir and Path(self.output_subdir).parts == parts[:len(Path(self.output_subdir).parts)]:
            return True
        return len(parts) == 1 and (rel.endswith(".log") or rel in self.records)

    def clean_after_failure(self) -> bool:
        """Undoes a failed run's records when it wrote nothing else (see the module docstring).

        Returns:
            True when the folder was cleaned, False when the run wrote results (left as they are).
        """
        if not self.folder.is_dir():
            self._remove_created_ancestors()
            return True
        folders_now: set[str] = set()
        now = dict(_walk(self.folder, folders_now))
        new = [rel for rel in now if rel not in self.sizes]
        if any(not self.is_record(rel) for rel in new):
            return False
        for rel in new:
            _unlink(now[rel])
        for rel, old in self.record_bytes.items():
            path = self.folder / rel
            if rel in now and path.read_bytes() != old:
                atomic_write(path, lambda f, data=old: f.write(data))
        for rel, size in self.sizes.items():
            if rel.endswith(".log") and rel in now and now[rel].stat().st_size > size:
                with open(now[rel], "r+b") as f:
                    f.truncate(size)
        for rel in sorted(folders_now - self.folders, key=lambda r: -len(Path(r).parts)):
            _rmdir_if_empty(self.folder / rel)
        if not self.existed:
            _rmdir_if_empty(self.folder)
            self._remove_created_ancestors()
        return True

    def _remove_created_ancestors(self) -> None:
        """The empty folders made to hold the run folder (e.g. ``outputs/infer/``), innermost first."""
        if self.first_missing is None:
            return
        for parent in self.folder.parents:
            if self.first_missing not in (parent, *parent.parents):
                break
            _rmdir_if_empty(parent)

    def remove_new_empty_logs(self) -> None:
        """After a success: a log file this run created and nothing wrote into is clutter."""
        if self.folder.is_dir():
            for path in self.folder.glob("*.log"):
                if path.name not in self.sizes and path.is_file() and path.stat().st_size == 0:
                    _unlink(path)


def _walk(folder: Path, folders: set[str]) -> Iterable[tuple[str, Path]]:
    for root, dirs, files in os.walk(folder):
        rel_root = os.path.relpath(root, folder)
        for d in dirs:
            folders.add(os.path.normpath(os.path.join(rel_root, d)))
        for name in files:
            path = Path(root, name)
            if path.is_file() and not path.is_symlink():
                yield os.path.normpath(os.path.join(rel_root, name)), path


def _unlink(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass


def _rmdir_if_empty(path: Path) -> None:
    try:
        path.rmdir()
    except OSError:
        pass


class _RunState:
    """What ``RunFolderGuard`` saw of the current command's run folder (one command at a time)."""

    snapshot: Optional[RunFolderSnapshot] = None
    prog: str = "sdfdiff"
    records: tuple[str, ...] = RUN_RECORDS


_RUN = _RunState()


class RunFolderGuard(Callback):
    """Hydra callback (added by ``hydra_entry``'s ``main()``): before hydra creates the run folder,
    takes its snapshot (``RunFolderSnapshot``), then creates it and writes a probe file into it, so
    that an unwritable run folder is one line and not hydra's traceback."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        try:
            folder = Path(os.path.abspath(str(OmegaConf.select(config, "hydra.run.dir"))))
        except Exception as err:  # e.g. output_dir=${nope}; left to hydra (a traceback) if not a user's
            message = user_message(err)
            if message is None:
                return
            _report(_RUN.prog, message)
        snap = _RUN.snapshot = RunFolderSnapshot.take(folder, OmegaConf.select(config, "hydra.output_subdir"),
                                                      _RUN.records)
        try:  # hydra turns a callback's exception into a warning: report it here
            make_writable_folder(folder)
        except OSError as err:
            snap.clean_after_failure()
            _report(_RUN.prog, f"cannot write the run folder {folder} ({err.strerror or err})")


def _report(prog: str, message: str) -> None:
    print(f"{prog}: error: {message}", file=sys.stderr, flush=True)
    raise SystemExit(USAGE_ERROR)


GUARD_OVERRIDE = f"+hydra.callbacks.sdfcommon_run_folder._target_={__name__}.RunFolderGuard"


def run_task(prog: str, task: Callable[[DictConfig], Any], cfg: DictConfig) -> Any:
    """Runs ``task(cfg)`` with the error handling and clean-up described in the module docstring
    (inside ``hydra.main``; ``hydra_entry`` calls it)."""
    from hydra.core.hydra_config import HydraConfig

    snap = _RUN.snapshot
    if snap is not None and HydraConfig.initialized() and \
            Path(HydraConfig.get().runtime.output_dir).resolve() != snap.folder.resolve():
        snap = None  # not the folder the guard saw (a multirun job): leave it alone
    try:
        result = task(cfg)
    except Exception as err:
        message = user_message(err)
        if snap is not None:
            snap.clean_after_failure()
        if message is None:
            raise
        _report(prog, message)
    if snap is not None:
        snap.remove_new_empty_logs()
    return result


def compose(config_name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """``configs/<config_name>.yaml`` composed with hydra ``overrides`` (hydra's compose API),
    outside a hydra run: for commands that compose their own config (the demo), benchmarks and data
    scripts. Entry points get theirs from ``hydra_entry``."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides))


def hydra_entry(prog: str, config_name: str, task: Callable[[DictConfig], Any],
                config_dir: Path = CONFIG_DIR, records: Sequence[str] = RUN_RECORDS) -> Callable[[], None]:
    """The ``main()`` of an entry point: hydra composes ``<config_dir>/<config_name>.yaml`` with the
    command line and ``task(cfg)`` runs under ``run_task``'s error handling.

    Args:
        prog: the command's name in error lines (e.g. "sdfdiff-infer").
        config_name: the primary config (e.g. "infer").
        task: the function that takes the composed config and does the work.
        config_dir: the folder of the configs (absolute: console scripts run from anywhere).
        records: names of the files the task writes at the top of the run folder about the run
            itself (not results), besides hydra's ``.hydra/`` and ``*.log``; a failed run that wrote
            nothing else is undone.
    Returns:
        ``main()``, for ``[project.scripts]`` and ``if __name__ == "__main__": main()``. It returns
        None (hydra.main does not pass the task's result on); the exit status is 0 on success,
        ``USAGE_ERROR`` (2) for a user's mistake, 1 for a bug, or the task's own ``SystemExit``.
    """
    import hydra

    @hydra.main(version_base="1.3", config_path=str(config_dir), config_name=config_name)
    def _hydra_main(cfg: DictConfig) -> Any:
        return run_task(prog, task, cfg)

    def main() -> None:
        _RUN.snapshot, _RUN.prog, _RUN.records = None, prog, tuple(records)
        argv = list(sys.argv)
        if GUARD_OVERRIDE not in sys.argv:
            sys.argv.append(GUARD_OVERRIDE)
        if not any(a.startswith("hydra.job.name=") for a in sys.argv[1:]):
            # hydra names the job (and its log, <name>.log) after the file that holds hydra.main,
            # which is this one for every entry point: name it after the command's config instead.
            sys.argv.append(f"hydra.job.name={config_name}")
        try:
            _hydra_main()
        finally:
            sys.argv[:] = argv
            _RUN.snapshot = None

    main.__doc__ = f"``{prog}``: hydra reads {config_name}.yaml and the command-line overrides, then runs " \
                   f"{getattr(task, '__module__', '')}.{getattr(task, '__name__', 'task')}."
    main.__module__ = getattr(task, "__module__", __name__)
    return main


# ------------------------------------------------------------------------------------------------
# Config getters: each names its key


_MISSING = object()


def config_value(cfg: DictConfig, key: str) -> Any:
    """``cfg``'s value at the dotted ``key`` as plain Python (lists and dicts resolved).

    Raises:
        omegaconf MissingMandatoryValue for ``???``; UserError when the key is not in the config.
    """
    value = OmegaConf.select(cfg, key, default=_MISSING, throw_on_missing=True)
    if value is _MISSING:
        fail(f"{key} is not set (the config has no such key)")
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def config_int(cfg: DictConfig, key: str, minimum: Optional[int] = None, maximum: Optional[int] = None) -> int:
    """An integer setting: ``batch_size=abc`` -> "batch_size must be an integer >= 1, got 'abc'"."""
    return check_int(config_value(cfg, key), key, minimum, maximum)


def config_float(cfg: DictConfig, key: str, minimum: Optional[float] = None,
                 maximum: Optional[float] = None) -> float:
    """A finite number (an int is accepted)."""
    return check_float(config_value(cfg, key), key, minimum, maximum)


def config_choice(cfg: DictConfig, key: str, choices: Sequence[Any]) -> Any:
    """One of ``choices`` (compared as given: ``true``/``false`` arrive as bools)."""
    value = config_value(cfg, key)
    if not any(type(value) is type(c) and value == c for c in choices):  # 1 is not True
        fail(f"{key} must be one of {', '.join(str(c) for c in choices)}, got {value!r}")
    return value


def config_ints(cfg: DictConfig, key: str, minimum: Optional[int] = None, maximum: Optional[int] = None,
                allow_null: bool = False) -> Optional[list[int]]:
    """A list of integers (``views=[0,6]``); a single integer is a list of one; null when allowed."""
    value = config_value(cfg, key)
    if value is None and allow_null:
        return None
    items = [value] if isinstance(value, int) and not isinstance(value, bool) else value
    if not isinstance(items, list):
        fail(f"{key} must be a list of integers{' or null' if allow_null else ''}, got {value!r}")
    return [check_int(v, f"{key}[{i}]", minimum, maximum) for i, v in enumerate(items)]


def config_bool(cfg: DictConfig, key: str) -> bool:
    """true or false."""
    value = config_value(cfg, key)
    if not isinstance(value, bool):
        fail(f"{key} must be true or false, got {value!r}")
    return value


def config_object(cfg: DictConfig, key: str, **kwargs: Any) -> Any:
    """Instantiates the ``_target_`` node at ``key`` (``hydra.utils.instantiate``), after checking
    its values against the target dataclass's field types (``check_field_types``): ``optim.lr=fast``
    -> "optim.lr must be a number, got 'fast'"."""
    from hydra.utils import get_class, instantiate

    node = OmegaConf.select(cfg, key, throw_on_missing=True)
    values = config_value(cfg, key)
    if isinstance(values, dict) and "_target_" in values:
        try:
            cls = get_class(values["_target_"])
        except Exception:  # let instantiate report an unknown target
            cls = None
        if cls is not None:
            check_field_types(cls, {k: v for k, v in values.items() if not k.startswith("_")}, key)
    return instantiate(node, **kwargs)


def _first_set(*values: Any) -> Any:
    return next((v for v in values if v is not None and v != ""), None)


def _config_options(group: str) -> str:
    return ", ".join(sorted(p.stem for p in (CONFIG_DIR / str(group)).glob("*.yaml")))


OmegaConf.register_new_resolver("first_set", _first_set, replace=True)
OmegaConf.register_new_resolver("config_options", _config_options, replace=True)


__all__ = ["hydra_entry", "compose", "run_task", "user_message", "UserError", "fail", "USAGE_ERROR", "RUN_RECORDS",
           "RunFolderGuard", "RunFolderSnapshot", "config_value", "config_int",
           "config_float", "config_choice", "config_ints", "config_bool", "config_object", "CONFIG_DIR"]
