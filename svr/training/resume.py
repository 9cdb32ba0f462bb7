"""Resuming a training run: which run a checkpoint belongs to, what it resumes from, and with which
config.

``ckpt_path=RUN`` (a run folder) or ``ckpt_path=RUN/<stage>/checkpoints/last.ckpt`` continues that
run in its own folder (``resume_arguments`` points hydra's run folder at it and keeps its
``.hydra/``), from its latest checkpoint, with its saved ``config.yaml``; the command line may
change only ``RESUMABLE_KEYS`` (``resume_config``; each change logged as a warning). SLURM batch
jobs get a run folder their requeued job finds and resumes (``slurm_arguments``).
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

from omegaconf import DictConfig, OmegaConf

from svr.inference.checkpoints import STAGES

log = logging.getLogger(__name__)

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"


def run_folder_of(ckpt_path: str | Path) -> Optional[Path]:
    """The training run a checkpoint belongs to: ``RUN`` for ``RUN/<stage>/checkpoints/<name>.ckpt``
    (or ``RUN/<stage>/hpc_ckpt_<n>.ckpt``) when ``RUN/config.yaml`` exists (a folder this module
    wrote); None otherwise."""
    p = Path(ckpt_path).expanduser().resolve()
    if p.parent.name == "checkpoints" and p.parent.parent.name in STAGES:
        run = p.parent.parent.parent
    elif p.name.startswith("hpc_ckpt_") and p.parent.name in STAGES:  # Lightning's SLURM checkpoints
        run = p.parent.parent
    else:
        return None
    return run if (run / "config.yaml").is_file() else None


def run_named_by(ckpt_path: str | Path) -> Optional[Path]:
    """The run a ``ckpt_path`` setting resumes: the folder itself when it holds a ``config.yaml``,
    else the run its checkpoint belongs to (``run_folder_of``); None for neither."""
    path = Path(ckpt_path).expanduser()
    return path.resolve() if (path / "config.yaml").is_file() else run_folder_of(path)


def latest_checkpoint(run_dir: str | Path, schedule: Sequence[str]) -> Optional[Path]:
    """What a stopped run resumes from: the newest of ``last.ckpt``, ``final.ckpt`` and Lightning's
    SLURM checkpoints (``<stage>/hpc_ckpt_<n>.ckpt``) of the latest scheduled stage that wrote one
    (None: no stage has)."""
    for stage in reversed(list(schedule)):
        d = Path(run_dir) / stage / "checkpoints"
        found = [d / n for n in ("final.ckpt", "last.ckpt") if (d / n).is_file()]
        found += [f for f in (Path(run_dir) / stage).glob("hpc_ckpt_*.ckpt") if f.is_file()]
        if found:
            return max(found, key=lambda f: f.stat().st_mtime_ns)
    return None


# What may differ from a run's saved config when it is resumed: where and how fast it runs, and
# how long the stages train. Everything else (model, data, losses, schedule) must stay.
RESUMABLE_KEYS = ("ckpt_path", "trainer.", "data.num_workers", "data.pin_memory", "data.progress",
                  "data.generation_workers", "stage.*.max_steps", "stage.*.max_time", "callbacks.progress_bar.")


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


def resume_config(saved: DictConfig, requested: DictConfig, overrides: Sequence[str]) -> tuple[DictConfig, list[str]]:
    """The config a resumed run goes on with: the run's saved ``config.yaml``, with the requested
    (freshly composed) config's values where they are allowed to change (``RESUMABLE_KEYS``).

    Only settings the command line names (``overrides``, hydra's syntax) count as requested; what
    it leaves at the defaults comes from the run. Raises ValueError naming requested settings that
    would change the run (the model, the data, ...).

    Returns:
        (config, the changes made, "key: old -> new").
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser

    saved_leaves = _leaves(OmegaConf.to_container(saved, resolve=True))
    requested_leaves = _leaves(OmegaConf.to_container(requested, resolve=True))
    touched: list[str] = []
    for o in OverridesParser.create().parse_overrides(list(overrides)):
        key = o.key_or_group
        if key.startswith("hydra"):
            continue
        if o.is_delete():
            raise ValueError(f"{o.input_line}: a resumed run keeps its settings; ~ (delete) is not possible")
        if (CONFIG_DIR / key).is_dir() and "." not in key:
            # A config group: its own key, or the whole config for a global one (experiment=...).
            touched.append(key if key in saved else "")
        else:
            touched.append(key)

    def requested_here(path: str) -> bool:
        return any(t == "" or path == t or path.startswith(t + ".") for t in touched)

    merged = saved.copy()
    changes, refused = [], []
    missing = object()
    for path in sorted(set(saved_leaves) | set(requested_leaves)):
        old, new = saved_leaves.get(path, missing), requested_leaves.get(path, missing)
        if old == new or not requested_here(path):
            continue
        if not _may_change(path):
            refused.append(path)
            continue
        OmegaConf.update(merged, path, None if new is missing else new, merge=False)
        changes.append(f"{path}: {None if old is missing else old!r} -> {None if new is missing else new!r}")
    if refused:
        shown = ", ".join(refused[:4]) + (f" and {len(refused) - 4} more" if len(refused) > 4 else "")
        raise ValueError(f"resuming a run keeps its config.yaml; the command line would change {shown}. Only "
                         f"{', '.join(k.rstrip('.') for k in RESUMABLE_KEYS)} may change (start a new run instead)")
    return merged, changes


def _override_value(argv: Sequence[str], key: str) -> Optional[str]:
    """The value of a ``key=value`` (or ``+key=value``) command-line override, the last one wins."""
    value = None
    for arg in argv:
        for prefix in (f"{key}=", f"+{key}=", f"++{key}="):
            if arg.startswith(prefix):
                value = arg[len(prefix):].strip("'\"")
    return value


def resume_arguments(argv: Sequence[str]) -> list[str]:
    """The hydra overrides that make a resume command run in the resumed run's own folder.

    ``ckpt_path`` naming a run folder, or a checkpoint inside one, resumes that run: hydra's run
    folder becomes it (unless ``hydra.run.dir`` is given: then the run is continued in a new
    folder), and hydra does not rewrite its ``.hydra/``. Nothing for multirun (``-m``).
    """
    if "-m" in argv or "--multirun" in argv or any(a.startswith("hydra.run.dir=") for a in argv):
        return []
    ckpt = _override_value(argv, "ckpt_path")
    if ckpt in (None, "", "null"):
        return []
    run = run_named_by(ckpt)
    if run is None:
        return []
    quoted = str(run).replace("\\", "\\\\").replace("'", "\\'")
    return [f"hydra.run.dir='{quoted}'", "hydra.output_subdir=null"]


def resumed_config(cfg: DictConfig, run_dir: Path, overrides: Sequence[str]) -> DictConfig:
    """``cfg`` for a fresh run; for a run resumed in its own folder, the folder's ``config.yaml``
    with the changes the command line may make (``resume_config``), each logged."""
    ckpt = cfg.get("ckpt_path")
    if ckpt is None:
        return cfg
    run = run_named_by(ckpt)
    if run is None or run != run_dir.resolve():
        return cfg
    saved = OmegaConf.load(run / "config.yaml")
    merged, changes = resume_config(saved, cfg, overrides)
    for change in changes:
        log.warning("resuming %s with a changed setting: %s", run, change)
    return merged


def slurm_arguments(argv: Sequence[str], environ: Mapping[str, str]) -> list[str]:
    """The hydra overrides that let SLURM's requeue continue a run (as Lightning intends: on the
    signal SLURM sends before the time limit, ``#SBATCH --signal=SIGUSR1@90``, Lightning saves
    ``<stage>/hpc_ckpt_<n>.ckpt`` and requeues the job; at the limit, SIGTERM saves ``last.ckpt``).

    In a SLURM batch job (not an interactive one, as Lightning tells them apart) the run folder is
    ``outputs/train/slurm-<job id>`` (``<array job>_<task>`` for arrays) unless ``hydra.run.dir``
    is given, so the requeued job finds it; when the job was requeued (``SLURM_RESTART_COUNT`` > 0)
    and names no ``ckpt_path``, it resumes that folder's latest checkpoint.
    """
    job = environ.get("SLURM_JOB_ID")
    if not job or environ.get("SLURM_JOB_NAME") in ("bash", "interactive"):
        return []
    if "-m" in argv or "--multirun" in argv or any(a.startswith("hydra.run.dir=") for a in argv):
        return []
    if environ.get("SLURM_ARRAY_JOB_ID") and environ.get("SLURM_ARRAY_TASK_ID"):
        job = f"{environ['SLURM_ARRAY_JOB_ID']}_{environ['SLURM_ARRAY_TASK_ID']}"
    run = Path("outputs") / "train" / f"slurm-{job}"
    out = [f"hydra.run.dir={run}"]
    requeued = int(environ.get("SLURM_RESTART_COUNT") or 0) > 0
    if requeued and _override_value(argv, "ckpt_path") in (None, "", "null") and (run / "config.yaml").is_file():
        out += [f"ckpt_path={run}", "hydra.output_subdir=null"]
    return out


__all__ = ["run_folder_of", "run_named_by", "latest_checkpoint", "resume_config", "resumed_config", "resume_arguments",
           "slurm_arguments", "RESUMABLE_KEYS"]
