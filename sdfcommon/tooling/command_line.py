"""A command's command line, looked at before hydra runs it (``commands.hydra_entry``). Hydra
reports an override it cannot compose (an unknown key ``foo=1``, a group option that does not
exist ``model=bogus``, a group the command does not have, an override it cannot parse) in several
lines with exit status 1, before any callback of ours runs; ``check_command_line`` composes the
config with the command line's overrides first, as hydra will (each job of a ``-m`` sweep), and
turns such an error into the commands' one line ``<prog>: error: <message>`` naming the key or
group, with exit status 2. ``--help`` is answered here too: hydra's help template with ``$CONFIG``
the composed settings, each with its comment from the YAML files it came from (hydra's own help
drops them). A command line that names another config (``--config-path``, ``--config-dir``) or
asks hydra for something else (``--info``, ``--shell-completion``, ``--experimental-rerun``) is
left to hydra.
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import importlib.resources
import os
import re
import shlex
import string
import sys
from pathlib import Path
from typing import Iterator, Mapping, Optional, Sequence

from hydra import compose, initialize_config_dir, initialize_config_module
from hydra._internal.utils import get_args_parser  # hydra.main's own parser: hydra has no public one
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import CompactHydraException, HydraException, MissingConfigException, OverrideParseException
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf, open_dict

from sdfcommon.tooling.config_comments import commented_yaml, yaml_comments

USAGE_ERROR = 2


def hydra_arguments(argv: Sequence[str]) -> argparse.Namespace:
    """The command line as hydra's own parser reads it (hydra parses ``sys.argv`` again when it
    runs; an argument it does not know ends here, as there, with argparse's usage and status 2)."""
    return get_args_parser().parse_args(list(argv))


def check_command_line(config_name: str, config_path: str, args: argparse.Namespace, prog: str) -> None:
    """Composes ``config_name`` with the command line's overrides as hydra will; where that fails,
    exits with one line ``<prog>: error: <message>`` and status 2 (``report_usage_error``). Answers
    ``--help`` (exit status 0). Returns otherwise, and where the command line is hydra's alone
    (see the module docstring).

    Args:
        config_name: the command's config (``train``).
        config_path: hydra_entry's: ``pkg://<module>`` or a folder.
        args: ``hydra_arguments``'s.
        prog: the command's name where its config cannot tell (``hydra.help.app_name``).
    """
    if (args.config_path is not None or args.config_dir is not None or args.info is not None
            or args.shell_completion or args.experimental_rerun is not None or GlobalHydra().is_initialized()):
        return
    config_name = args.config_name or config_name
    overrides = list(args.overrides)
    with _initialized(config_path):
        try:
            jobs = _jobs(overrides, multirun=args.multirun or "hydra.mode=MULTIRUN" in overrides)
            composed = [compose(config_name, job, return_hydra_config=True) for job in jobs]
        except CompactHydraException as err:
            base = _compose_without(config_name, overrides, err)
            if base is None:
                return  # the config itself does not compose: hydra reports it
            report_usage_error(_prog(base, prog), composition_message(err, base, overrides))
        except Exception:
            return  # not a composition error of the command line (a broken config): hydra reports it
        if args.help:
            print(_help_text(composed[0], config_name, jobs[0], args))
            raise SystemExit(0)


def invoked_as(default: str) -> str:
    """The start of a command line that runs this command again the way the user started it, for
    advice they can paste (``Resume with: <this> ckpt_path=...``): ``python train.py`` for a
    script, ``python -m <module>``, the console script's name (``sdfdiff-train``), or ``default``
    when it was started otherwise (by a test runner)."""
    argv = list(getattr(sys, "orig_argv", None) or [sys.executable, *sys.argv])
    if len(argv) >= 3 and argv[1] == "-m" and argv[2] not in ("pytest", "unittest"):
        return f"python -m {argv[2]}"
    script = sys.argv[0] if sys.argv else ""
    name = os.path.basename(script)
    if name.startswith("sdfdiff-"):
        return name
    if name.endswith(".py") and len(argv) >= 2 and argv[1] == script:
        return f"python {shlex.quote(script)}"
    return default


def report_usage_error(prog: str, message: str) -> None:
    """The one line of a user's mistake, ``<prog>: error: <message>`` on stderr, and exit status 2."""
    print(f"{prog}: error: {message}", file=sys.stderr, flush=True)
    raise SystemExit(USAGE_ERROR)


@contextlib.contextmanager
def _initialized(config_path: str) -> Iterator[None]:
    if config_path.startswith("pkg://"):
        with initialize_config_module(config_module=config_path[len("pkg://"):], version_base="1.3"):
            yield
    else:  # a folder: relative to this package's, as hydra.main takes it from hydra_entry's module
        folder = os.path.join(os.path.dirname(os.path.abspath(__file__)), config_path)
        with initialize_config_dir(config_dir=os.path.abspath(folder), version_base="1.3"):
            yield


def _jobs(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The override lists hydra composes: the command line's, or under ``-m`` one per value of the
    longest sweep (the other sweeps cycle), so every value of every sweep is composed once."""
    if not multirun:
        return [overrides]
    parsed = OverridesParser.create().parse_overrides(overrides)
    plain, sweeps = [], []
    for o in parsed:
        if not o.is_sweep_override():
            plain.append(o.input_line)
            continue
        try:
            sweeps.append([f"{o.get_key_element()}={v}" for v in o.sweep_string_iterator()])
        except HydraException:
            continue  # a glob over a group's options: the options exist by construction
    sweeps = [s for s in sweeps if s]
    if not sweeps:
        return [plain]
    return [plain + [s[i % len(s)] for s in sweeps] for i in range(max(map(len, sweeps)))]


def _compose_without(config_name: str, overrides: list[str], err: Exception) -> Optional[DictConfig]:
    """The config without the override that failed (the keys a message can list), or without any."""
    key = _failed_key(err)
    kept = [o for o in overrides if _override_key(o) != key] if key else []
    for attempt in ([kept] if kept else []) + [[]]:
        try:
            return compose(config_name, attempt, return_hydra_config=True)
        except Exception:
            continue
    return None


def _override_key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~").split("@", 1)[0]


def _failed_key(err: Exception) -> Optional[str]:
    """The key or group hydra could not compose (its messages quote it first)."""
    if isinstance(err, MissingConfigException) and err.missing_cfg_file and "/" in err.missing_cfg_file:
        return err.missing_cfg_file.rsplit("/", 1)[0]
    first = str(err).splitlines()[0] if str(err) else ""
    quoted = re.search(r"'([^']+)'", first) if first.startswith("Could not") else None
    return quoted.group(1) if quoted else None


def composition_message(err: Exception, base: DictConfig, overrides: Sequence[str]) -> str:
    """The one line of hydra's composition error ``err`` (see the module docstring).

    Args:
        err: hydra's ``CompactHydraException``.
        base: the config composed without the failing override (the keys and groups to list).
        overrides: the command line's overrides (to quote the failing one).
    """
    text = str(err)
    first = text.splitlines()[0].strip() if text.strip() else type(err).__name__
    if isinstance(err, MissingConfigException) and err.missing_cfg_file and err.options is not None \
            and "/" in err.missing_cfg_file:
        group, option = err.missing_cfg_file.rsplit("/", 1)
        return f"{group}={option}: no such option ({group} has: {', '.join(err.options)})"
    if isinstance(err, OverrideParseException):
        return f"cannot read the override {err.override!r}: {first}"
    key = _failed_key(err)
    given = next((o for o in overrides if _override_key(o) == key), f"{key}=...")
    if key and first.startswith("Could not override") and "No match in the defaults list" in text:
        groups = sorted(g for g, _ in _choices(base) if not g.startswith("hydra"))
        return (f"{key}: {_prog(base, 'this command')} has no config group {key} "
                f"({'its groups: ' + ', '.join(groups) if groups else 'it has none'})")
    if key and first.startswith("Could not override"):
        return _unknown_key_message(key, base, given)
    if key and first.startswith("Could not append"):
        return f"{given}: {key} is in the config already: set it with {given.lstrip('+')}"
    if key and first.startswith("Could not delete"):
        return f"{given}: {key} is not in the config"
    if first.startswith("Ambiguous value"):
        return f"{first}: a list is key=[a,b], a string key='a,b', a sweep needs --multirun"
    return first


def _choices(cfg: DictConfig) -> list[tuple[str, Optional[str]]]:
    choices = OmegaConf.select(cfg, "hydra.runtime.choices", default=None)
    return list(choices.items()) if choices is not None else []


def _unknown_key_message(key: str, base: DictConfig, given: str) -> str:
    """``"<key>: unknown setting (<owner> has: a, b, ...)"``, the owner named by its ``_target_``."""
    parts = key.split(".")
    node: object = base
    for i, part in enumerate(parts):
        if not isinstance(node, DictConfig) or part not in node.keys():  # keys(): nothing resolved
            break
        node = OmegaConf.select(base, ".".join(parts[:i + 1]), throw_on_resolution_failure=False)
    else:
        return f"{key}: unknown setting"
    if not isinstance(node, DictConfig):
        return f"{key}: {'.'.join(parts[:i])} is a value, not a group of settings"
    names = [str(k) for k in node.keys() if not (str(k).startswith("_") and str(k).endswith("_"))
             and not (i == 0 and k == "hydra")]
    target = node.get("_target_") if "_target_" in node else None
    owner = str(target).rsplit(".", 1)[-1] if target else (".".join(parts[:i]) or "the config")
    line = f"{'.'.join(parts[:i + 1])}: unknown setting ({owner} has: {', '.join(names)})"
    if i > 0 and target:  # a component's keyword argument the YAML leaves out may be added
        line += f"; to pass one the config does not list: +{given.lstrip('+~')}"
    return line


def _prog(cfg: DictConfig, default: str) -> str:
    return str(OmegaConf.select(cfg, "hydra.help.app_name", default=None) or default)


# ------------------------------------------------------------------------------------------------
# --help with the YAML comments


def settings_comments(config_name: str, overrides: Sequence[str],
                      choices: Mapping[str, Optional[str]]) -> dict[str, list[str]]:
    """Dotted key -> comment lines of the settings of ``config_name`` composed with ``overrides``,
    from every YAML file of its defaults list in composition order (a later file's comment on a
    key replaces an earlier one's; a key it sets without a comment keeps the earlier comment); a
    config group's node is labelled with its choice (``data=procedural``). Hydra must be
    initialised (``hydra_entry``'s hydra or hydra's compose API).

    Args:
        config_name, overrides: the command's config and the command line's overrides.
        choices: group -> chosen option (the composed config's ``hydra.runtime.choices``).
    """
    loader = GlobalHydra.instance().config_loader()
    found: dict[str, list[str]] = {}
    labels: dict[str, str] = {}
    for default in loader.compute_defaults_list(config_name, list(overrides), RunMode.RUN).defaults:
        package = default.package or ""
        if package == "hydra" or package.startswith("hydra.") or default.config_path is None:
            continue
        group, _, option = default.config_path.rpartition("/")
        if package and group and choices.get(group) == option:
            labels[package] = f"{group}={option}"
        text = _config_text(loader, default.config_path)
        if text is not None:
            found.update(yaml_comments(text, package))
    for package, label in labels.items():
        found[package] = [label, *found.get(package, [])]
    return found


def _config_text(loader, config_path: Optional[str]) -> Optional[str]:
    """The YAML text of a config of hydra's search path (None for a structured config)."""
    if config_path is None:
        return None
    for source in loader.get_sources():
        if not source.is_config(config_path):
            continue
        name = f"{config_path}.yaml"
        if source.scheme() == "file":
            return Path(source.path, name).read_text(encoding="utf-8")
        if source.scheme() == "pkg":
            return importlib.resources.files(source.path).joinpath(name).read_text(encoding="utf-8")
        return None
    return None


def _help_text(cfg: DictConfig, config_name: str, overrides: Sequence[str], args: argparse.Namespace) -> str:
    """Hydra's app help (``hydra.help.template``) with ``$CONFIG`` the commented settings."""
    HydraConfig.instance().set_config(cfg)  # as hydra's help does: templates may use ${hydra:...}
    settings_only = copy.deepcopy(cfg)
    with open_dict(settings_only):
        del settings_only["hydra"]
    settings = OmegaConf.to_container(settings_only, resolve=bool(args.resolve))
    hydra = GlobalHydra.instance().hydra
    return string.Template(cfg.hydra.help.template).substitute(
        FLAGS_HELP=hydra.format_args_help(get_args_parser()),
        HYDRA_CONFIG_GROUPS=hydra.format_config_groups(lambda g: g.startswith("hydra/") or g == "hydra"),
        APP_CONFIG_GROUPS=hydra.format_config_groups(lambda g: not (g.startswith("hydra/") or g == "hydra")),
        CONFIG=commented_yaml(settings, settings_comments(config_name, overrides, dict(_choices(cfg)))))


__all__ = ["check_command_line", "hydra_arguments", "report_usage_error", "composition_message", "settings_comments",
           "invoked_as", "USAGE_ERROR"]
