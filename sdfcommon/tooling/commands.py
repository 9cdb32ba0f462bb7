"""The command layer shared by every hydra command: ``hydra_entry(config_name, run)`` is a
command's ``main()`` (hydra composes the shipped config, ``build_settings`` turns it into the
command's typed settings, ``run(settings)`` works), and ``RunFolderGuard``, the hydra callback that
``configs/hydra/default.yaml`` installs, gives every command one error handling: a user's mistake
(ValueError, TypeError, OSError, omegaconf's missing or invalid keys, a hydra instantiation caused
by one of those) is ONE line ``<prog>: error: <message>`` with exit status 2, checked before the run
folder is made where it can be; a bug keeps hydra's traceback (exit status 1); ``SystemExit`` passes
untouched (143 after SIGTERM). Before hydra runs, ``command_line`` composes the command line once:
an override hydra cannot compose (an unknown key, a group option that does not exist) is the same
one line, where hydra would print several with status 1, and ``--help`` shows every setting with
its YAML comment. A failed run that wrote nothing but its records (``.hydra/``,
``*.log``, ``RUN_RECORDS``) leaves nothing behind: what it created goes, what existed before is
restored to its bytes; a run that wrote results keeps them. Resolvers registered on import:
``${first_set:a,b}`` (the first argument that is set), ``${config_options:group}`` (a group's
options, for help texts) and ``${default_data_dir:}`` (``paths.data_dir``'s default,
``default_data_dir``)."""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Optional, Sequence

import importlib.resources

import hydra
from hydra import compose as hydra_compose
from hydra import initialize_config_module
from hydra.core.utils import JobReturn, JobStatus
from hydra.errors import InstantiationException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf
from omegaconf import errors as oc_errors
from PIL import Image

from sdfcommon.tooling.command_line import USAGE_ERROR, check_command_line, hydra_arguments, report_usage_error
from sdfcommon.tooling.outputs import atomic_write, make_writable_folder
from sdfcommon.tooling.serialization import scrub_unsafe_advice
from sdfcommon.tooling.settings import build_settings

# The configs ship with the package as the module ``sdfdiff_configs`` (the repository's configs/
# folder, pyproject.toml's package-dir): console scripts find them wherever they run.
CONFIG_MODULE = "sdfdiff_configs"
CONFIG_PATH = f"pkg://{CONFIG_MODULE}"
DEFAULT_PROG = "sdfdiff"  # a command's name in messages where its config has no hydra.help.app_name
# Files a run writes about itself (not results): cleaned after a failed run that wrote nothing else.
RUN_RECORDS = ("config.yaml", "settings.json")
CHECKOUT_DATA_DIR = "data/cache"  # datasets of commands run in the checkout (default_data_dir)
_RECORD_BYTES = 1 << 20  # records above this are not restored (a config or settings file is a few KiB)


# ------------------------------------------------------------------------------------------------
# Which errors are a user's, and their one line


def _user_error_types() -> tuple[type, ...]:
    return (ValueError, TypeError, OSError, oc_errors.MissingMandatoryValue, oc_errors.ValidationError,
            oc_errors.ConfigKeyError, oc_errors.ConfigAttributeError, oc_errors.InterpolationResolutionError,
            Image.DecompressionBombError)


def user_message(err: BaseException) -> Optional[str]:
    """The one-line message of a user's mistake, or None when ``err`` is not one (a bug).

    A hydra ``InstantiationException`` is judged by its cause (``raise ... from``) and named by its
    config key; one without a cause (a ``_target_`` that cannot be found) is a user's mistake.
    """
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


class RunFolderGuard(Callback):
    """The hydra callback of every command (``configs/hydra/default.yaml``): the one error handling
    and clean-up described in the module docstring.

    Before hydra creates the run folder (``on_run_start``) it builds the command's settings as the
    command will (``build_settings``: an unknown or mistyped key is one line, and nothing is made), takes the
    folder's snapshot and checks that the folder can be created and written. After the job
    (``on_job_end``) it undoes a failed run's records and reports a user's mistake in one line;
    a bug is left to hydra (its traceback, exit status 1). The command's name in messages is
    ``hydra.help.app_name``.

    Args:
        records: names of the files the command writes at the top of the run folder about the run
            itself (not results), besides hydra's ``.hydra/`` and ``*.log``.
    """

    def __init__(self, records: Sequence[str] = RUN_RECORDS) -> None:
        self.records = tuple(records)
        self.snapshot: Optional[RunFolderSnapshot] = None

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        prog = _prog(config)
        try:
            folder = Path(os.path.abspath(str(OmegaConf.select(config, "hydra.run.dir"))))
            build_settings(config)
        except Exception as err:
            message = user_message(err)
            if message is None:
                raise
            report_usage_error(prog, message)
        snap = self.snapshot = RunFolderSnapshot.take(folder, OmegaConf.select(config, "hydra.output_subdir"),
                                                      self.records)
        try:
            make_writable_folder(folder)
        except OSError as err:
            snap.clean_after_failure()
            report_usage_error(prog, f"cannot write the run folder {folder} ({err.strerror or err})")

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        snap = self.snapshot
        if snap is not None and Path(config.hydra.runtime.output_dir).resolve() != snap.folder.resolve():
            snap = None  # not the folder seen before the run (a multirun job): leave it alone
        if job_return.status != JobStatus.FAILED:
            if snap is not None:
                snap.remove_new_empty_logs()
            return
        err = job_return._return_value  # the task's exception (hydra raises it after the callbacks)
        if snap is not None:
            snap.clean_after_failure()
        message = user_message(err) if isinstance(err, BaseException) else None
        if message is not None:
            report_usage_error(_prog(config), message)


def _prog(config: DictConfig) -> str:
    return str(OmegaConf.select(config, "hydra.help.app_name", default=None) or DEFAULT_PROG)


def compose(config_name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """``configs/<config_name>.yaml`` composed with hydra ``overrides`` (hydra's compose API),
    outside a hydra run: for commands that compose their own config (the demo), benchmarks and data
    scripts. Entry points get theirs from ``hydra_entry``."""
    with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides))


def hydra_entry(config_name: str, run: Callable[[Any], Any], config_path: str = CONFIG_PATH) -> Callable[[], None]:
    """The ``main()`` of a command: hydra composes ``<config_name>.yaml`` (of the configs shipped
    with the package) with the command line, the composed config becomes the command's typed
    settings (``build_settings``: its ``_target_`` dataclass) and ``run(settings)`` does the work.
    The command line is composed once before hydra runs it (``command_line.check_command_line``:
    an unknown key or group option is one line, ``--help`` shows the settings with their YAML
    comments); the run-folder guard and the error handling come from the config
    (``RunFolderGuard``).

    Returns:
        ``main()``, for ``[project.scripts]`` and ``if __name__ == "__main__": main()``; the exit
        status is 0 on success, ``USAGE_ERROR`` (2) for a user's mistake, 1 for a bug, or the
        command's own ``SystemExit``.
    """

    @hydra.main(version_base="1.3", config_path=config_path, config_name=config_name)
    def hydra_main(cfg: DictConfig) -> Any:
        return run(build_settings(cfg))

    def main() -> Any:
        check_command_line(config_name, config_path, hydra_arguments(sys.argv[1:]), DEFAULT_PROG)
        return hydra_main()

    main.__doc__ = f"hydra reads {config_name}.yaml and the command line, then runs " \
                   f"{getattr(run, '__module__', '')}.{getattr(run, '__name__', 'run')}(settings)."
    return main


def _first_set(*values: Any) -> Any:
    return next((v for v in values if v is not None and v != ""), None)


def config_folder() -> importlib.resources.abc.Traversable:
    """The shipped configs folder (``configs/`` of the checkout in an editable install)."""
    return importlib.resources.files(CONFIG_MODULE)


def config_group_options(group: str) -> list[str]:
    """The options of a config group (``data`` -> ["nmr", "procedural", ...]); [] for none."""
    folder = config_folder()
    for part in str(group).split("/"):
        folder = folder / part
    if not folder.is_dir():
        return []
    return sorted(p.name[:-len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def project_checkout() -> Optional[Path]:
    """The source checkout the shipped configs come from (an editable install), or None when the
    package was installed from a wheel."""
    folder = config_folder()
    if not isinstance(folder, Path):
        return None
    root = folder.parent
    return root if (root / "train.py").is_file() and (root / "pyproject.toml").is_file() else None


def user_cache_dir() -> Path:
    """This project's folder in the user's cache: ``$XDG_CACHE_HOME/sdfdiff`` (``~/.cache/sdfdiff``)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or "~/.cache").expanduser() / "sdfdiff"


def default_data_dir() -> str:
    """Where generated datasets go unless ``paths.data_dir`` says otherwise:
    ``data/cache`` when the command runs in the project's checkout (the README's commands), else
    ``user_cache_dir()``, so a command started in any other folder never fills it with data."""
    root = project_checkout()
    if root is not None and Path.cwd().resolve() == root.resolve():
        return CHECKOUT_DATA_DIR
    return str(user_cache_dir())


def _config_options(group: str) -> str:
    return ", ".join(config_group_options(group))


OmegaConf.register_new_resolver("first_set", _first_set, replace=True)
OmegaConf.register_new_resolver("config_options", _config_options, replace=True)
OmegaConf.register_new_resolver("default_data_dir", default_data_dir, replace=True)


__all__ = ["hydra_entry", "compose", "user_message", "USAGE_ERROR", "RUN_RECORDS",
           "RunFolderGuard", "RunFolderSnapshot", "CONFIG_MODULE", "config_folder", "config_group_options",
           "project_checkout", "user_cache_dir", "default_data_dir", "CHECKOUT_DATA_DIR"]
