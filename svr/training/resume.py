"""Resuming a training run: ``ckpt_path=RUN`` (a run folder) or a checkpoint inside one continues
that run in its own folder (hydra's run folder is set to it by the ``train_run_dir`` resolver of
configs/train.yaml), from its latest checkpoint, with its saved ``config.yaml``; the command line
may change only ``RESUMABLE_KEYS`` (``resume_config``; each change logged as a warning). A SLURM
batch job gets a run folder its requeued job finds and resumes (``slurm_run_folder``)."""
from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

from hydra import compose
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf

from sdfcommon.tooling.commands import config_group_options
from sdfcommon.tooling.settings import build_settings, settings_record
from svr.training.run_folder import RunFolder, run_named_by
from svr.training.settings import TrainSettings

log = logging.getLogger(__name__)


# What may differ from a run's saved config when it is resumed: where and how fast it runs, and
# how long the stages train. Everything else (model, data, losses, schedule) must stay.
RESUME_KEY = "ckpt_path"  # names the run (or checkpoint) to go on with
RESUMABLE_KEYS = (RESUME_KEY, "trainer.", "data.num_workers", "data.pin_memory", "data.progress",
                  "data.generation_workers", "stage.*.max_steps", "stage.*.max_time", "callbacks.progress_bar.")

# Of those, what changes only what the run prints (progress bars): logged, not warned about.
DISPLAY_KEYS = ("data.progress", "trainer.enable_progress_bar", "trainer.enable_model_summary", "callbacks.progress_bar")


def _display_only(change: str) -> bool:
    key = change.split(":", 1)[0]
    return any(key == k or key.startswith(k + ".") for k in DISPLAY_KEYS)


def _may_change(key: str) -> bool:
    parts = key.split(".")
    for pattern in RESUMABLE_KEYS:
        pat = pattern.rstrip(".").split(".")
        if len(parts) < len(pat) or (not pattern.endswith(".") and len(parts) != len(pat)):
            continue
        if all(q == "*" or q == k for q, k in zip(pat, parts)):
            return True
    return False


def _leaves(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict) and node:
        out: dict[str, Any] = {}
        for k, v in node.items():
            out.update(_leaves(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: node}


def _known(leaves: dict[str, Any], path: str) -> bool:
    """Whether the config of these leaves sets ``path``, a part of it or a whole node above it."""
    return any(k == path or path.startswith(k + ".") or k.startswith(path + ".") for k in leaves)


def _same_component(saved: dict[str, Any], requested: dict[str, Any], path: str) -> bool:
    """Whether ``path`` lies in the same component in both configs: the nearest node above it that
    names a ``_target_`` in ``requested`` names the same one in ``saved``, or ``saved`` lacks that
    node altogether (a component the saved run did not have). A default of another class (the
    procedural data's ``cache_dir`` for an NMR run) never belongs to the saved run's node."""
    parts = path.split(".")
    for i in range(len(parts) - 1, 0, -1):
        node = ".".join(parts[:i])
        if f"{node}._target_" in requested:
            return not _known(saved, node) or saved.get(f"{node}._target_") == requested[f"{node}._target_"]
    return True


def resume_config(saved: DictConfig, requested: DictConfig, overrides: Sequence[str]) -> tuple[DictConfig, list[str]]:
    """The config a resumed run goes on with: the run's saved ``config.yaml``, with the requested
    (freshly composed) config's values where they are allowed to change (``RESUMABLE_KEYS``).

    Only settings the command line names (``overrides``, hydra's syntax) count as requested; what
    it leaves at the defaults comes from the run. Raises ValueError naming requested settings that
    would change the run (the model, the data, ...).

    Returns:
        (config, the changes made, "key: old -> new").
    """
    saved_leaves = _leaves(OmegaConf.to_container(saved, resolve=True))
    requested_leaves = _leaves(OmegaConf.to_container(requested, resolve=True))
    touched: list[str] = []
    for o in OverridesParser.create().parse_overrides(list(overrides)):
        key = o.key_or_group
        if key.startswith("hydra"):
            continue
        if o.is_delete():
            raise ValueError(f"{o.input_line}: a resumed run keeps its settings; ~ (delete) is not possible")
        if "." not in key and config_group_options(key):
            # A config group: its own key, or the whole config for a global one (experiment=...).
            touched.append(key if key in saved else "")
        else:
            touched.append(key)

    def requested_here(path: str, named_only: bool = False) -> bool:
        return any((t == "" and not named_only) or t and (path == t or path.startswith(t + ".")) for t in touched)

    merged = saved.copy()
    changes, refused = [], []
    missing = object()
    for path in sorted(set(saved_leaves) | set(requested_leaves)):
        old, new = saved_leaves.get(path, missing), requested_leaves.get(path, missing)
        if old == new or new is missing and not requested_here(path):
            continue
        if old is missing and not requested_here(path, named_only=True):
            # A setting the saved run did not know yet takes its default, also under a global group
            # (experiment=...) that did not name it.
            if not _known(saved_leaves, path) and _same_component(saved_leaves, requested_leaves, path):
                OmegaConf.update(merged, path, new, merge=False)
            continue
        if not requested_here(path):
            continue
        if not _may_change(path):
            refused.append(path)
            continue
        OmegaConf.update(merged, path, None if new is missing else new, merge=False)
        if path == RESUME_KEY:
            continue  # the request to resume, not a change of the run's settings
        changes.append(f"{path}: {None if old is missing else old!r} -> {None if new is missing else new!r}")
    if refused:
        shown = ", ".join(refused[:4]) + (f" and {len(refused) - 4} more" if len(refused) > 4 else "")
        raise ValueError(f"resuming a run keeps its config.yaml; the command line would change {shown}. Only "
                         f"{', '.join(k.rstrip('.') for k in RESUMABLE_KEYS)} may change (start a new run instead)")
    return merged, changes


def run_group_choices(run: RunFolder) -> dict[str, str]:
    """The config-group options a run was started with (``data: nmr``, ``experiment: demo``, ...),
    from hydra's record of its start (``RunFolder.hydra_record``), hydra's own groups left out; {}
    without that record (a demo's run folder, a run folder copied without its ``.hydra/``)."""
    if not run.hydra_record.is_file():
        return {}
    choices = OmegaConf.select(OmegaConf.load(run.hydra_record), "hydra.runtime.choices", default=None) or {}
    return {str(group): str(option) for group, option in choices.items()
            if option is not None and group != "hydra" and not str(group).startswith("hydra/")}


def run_defaults(run: RunFolder, overrides: Sequence[str], config_name: str = "train") -> Optional[DictConfig]:
    """The config a command line with ``overrides`` composes when it takes the config-group options
    of the run it resumes (``run_group_choices``; a group the command line names keeps its choice):
    where the settings the saved run lacks take their defaults from, so that they come from the
    run's own groups (an NMR run's from ``data=nmr``, never the default ``data=procedural``). None
    without hydra's record of the run, outside a hydra command, or when the run's options no longer
    compose (``resume_config`` then keeps other components' defaults out)."""
    choices = run_group_choices(run)
    if not choices or not GlobalHydra.instance().is_initialized():
        return None
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    named = {o.key_or_group for o in parsed}
    asked = [o.input_line for o in parsed if not o.key_or_group.startswith("hydra")]
    try:
        return compose(config_name, overrides=[*(f"{g}={o}" for g, o in choices.items() if g not in named), *asked])
    except HydraException as err:
        log.warning("the config groups of %s (%s) do not compose any more (%s); settings it lacks take the "
                    "command line's defaults", run.root, choices, err)
        return None


def resumed_settings(settings: TrainSettings, run: RunFolder, overrides: Sequence[str]) -> tuple[TrainSettings, dict]:
    """The settings a training command goes on with in ``run`` (hydra's run folder), and the record
    to write as its ``config.yaml``: for a fresh run ``settings``; for a run resumed in its own
    folder (``ckpt_path`` names it), ``continued_settings`` with the defaults of the run's own config
    groups (``run_defaults``)."""
    named = run_named_by(settings.ckpt_path) if settings.ckpt_path is not None else None
    if named is None or named.root != run.root.resolve():
        return settings, settings_record(settings)
    return continued_settings(settings, named, overrides, run_defaults(named, overrides))


def continued_settings(settings: TrainSettings, run: RunFolder, overrides: Sequence[str],
                       defaults: Optional[DictConfig] = None) -> tuple[TrainSettings, dict]:
    """The settings a run already in ``run`` goes on with: its saved ``config.yaml`` with the
    changes the command line may make (``resume_config``; each logged as a warning, or as
    information where it changes only the output's progress bars, ``DISPLAY_KEYS``), and the record
    to write back (keeping the ``ckpt_path`` the run started from). Settings the saved run did not
    know yet take their values from ``defaults`` (the composed config of the run's own groups,
    ``run_defaults``), else from ``settings``."""
    saved = OmegaConf.load(run.config)
    requested = defaults if defaults is not None else OmegaConf.create(settings_record(settings))
    merged, changes = resume_config(saved, requested, overrides)
    for change in changes:
        (log.info if _display_only(change) else log.warning)("resuming %s with a changed setting: %s", run.root, change)
    record = OmegaConf.to_container(merged, resolve=True)
    resumed = build_settings(record)
    record["ckpt_path"] = saved.get("ckpt_path")
    return resumed, record


def _is_set(value: Any) -> bool:
    return value not in (None, "", "null", "None")


def slurm_run_folder(environ: Mapping[str, str], output_dir: str) -> Optional[RunFolder]:
    """The run folder of a SLURM batch job, ``<output_dir>/train/slurm-<job id>`` (``<array
    job>_<task>`` for arrays), so that its requeued job finds it (as Lightning intends: on the
    signal SLURM sends before the time limit, ``#SBATCH --signal=SIGUSR1@90``, Lightning saves
    ``<stage>/hpc_ckpt_<n>.ckpt`` and requeues the job; at the limit, SIGTERM saves ``last.ckpt``).
    None outside a batch job (interactive jobs, as Lightning tells them apart, included)."""
    job = environ.get("SLURM_JOB_ID")
    if not job or environ.get("SLURM_JOB_NAME") in ("bash", "interactive"):
        return None
    if environ.get("SLURM_ARRAY_JOB_ID") and environ.get("SLURM_ARRAY_TASK_ID"):
        job = f"{environ['SLURM_ARRAY_JOB_ID']}_{environ['SLURM_ARRAY_TASK_ID']}"
    return RunFolder(Path(output_dir) / "train" / f"slurm-{job}")


def requeued_run(environ: Mapping[str, str], output_dir: str) -> Optional[RunFolder]:
    """The run a requeued SLURM job (``SLURM_RESTART_COUNT`` > 0) goes on with, when its folder
    holds one; None otherwise."""
    run = slurm_run_folder(environ, output_dir)
    requeued = int(environ.get("SLURM_RESTART_COUNT") or 0) > 0
    return run if requeued and run is not None and run.holds_run() else None


def train_run_dir(ckpt_path: Any, output_dir: str, fresh: str) -> str:
    """hydra's run folder for training (the resolver ``${train_run_dir:ckpt_path,output_dir,fresh}``
    of configs/train.yaml): the run ``ckpt_path`` names (resuming it in its own folder), else a
    SLURM batch job's folder (``slurm_run_folder``), else ``fresh`` (a new folder)."""
    if _is_set(ckpt_path):
        run = run_named_by(str(ckpt_path))
        if run is not None:
            return str(run.root)
    slurm = slurm_run_folder(os.environ, output_dir)
    return str(slurm.root) if slurm is not None else str(fresh)


def train_output_subdir(ckpt_path: Any, run_dir: str, output_dir: str) -> Optional[str]:
    """hydra's record folder for training (``${train_output_subdir:ckpt_path,run_dir,output_dir}``):
    none when the run goes on in the folder of the run it resumes, named by ``ckpt_path`` or a
    requeued SLURM job's own (``requeued_run``; its ``.hydra/`` keeps the record of how it started),
    ``.hydra`` otherwise."""
    folder = Path(str(run_dir)).expanduser().resolve()
    resumed = run_named_by(str(ckpt_path)) if _is_set(ckpt_path) else requeued_run(os.environ, output_dir)
    return None if resumed is not None and resumed.root.resolve() == folder else ".hydra"


OmegaConf.register_new_resolver("train_run_dir", train_run_dir, replace=True)
OmegaConf.register_new_resolver("train_output_subdir", train_output_subdir, replace=True)


__all__ = ["resume_config", "resumed_settings", "continued_settings", "run_group_choices", "run_defaults",
           "slurm_run_folder", "requeued_run", "train_run_dir", "train_output_subdir", "RESUMABLE_KEYS"]
