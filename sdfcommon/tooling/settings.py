"""Typed settings from composed configs: a config node whose ``_target_`` names a dataclass becomes
an instance of it, after every key is checked against the dataclass's fields (an unknown key is an
error naming it) and every value against the field's annotation (``check_field_types``). Fields
annotated with a dataclass are built the same way, recursively; fields annotated ``Component``
(a plain ``dict``) hold a node with its own ``_target_`` that the command instantiates when it
needs it (``hydra.utils.instantiate``), e.g. a data module or a network."""
from __future__ import annotations

import collections.abc
import dataclasses
import importlib
import typing
from dataclasses import dataclass
from collections.abc import Mapping
from typing import Any, Optional, Union

from hydra.utils import get_class
from omegaconf import DictConfig, OmegaConf

from sdfcommon.tooling.checks import check_field_types

# A component's config: a plain dict with a ``_target_``, instantiated by the command that owns it.
Component = dict


@dataclass(frozen=True)
class PathSettings:
    """Where commands write and read (configs/paths/default.yaml): ``output_dir`` holds the runs of
    every command (``train/``, ``eval/``, ``infer/``, ``demo``), ``data_dir`` the generated and
    prepared datasets. Relative paths are taken from the working directory."""

    output_dir: str
    data_dir: str



def _dataclass_of(hint: Any) -> Optional[type]:
    """The dataclass an annotation names (also inside Optional[...]), or None."""
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return hint
    if typing.get_origin(hint) is Union:
        found = [a for a in typing.get_args(hint) if dataclasses.is_dataclass(a) and isinstance(a, type)]
        return found[0] if len(found) == 1 else None
    return None


def _dataclasses_in(hint: Any) -> tuple[type, ...]:
    """The dataclasses an annotation's items may be, for a ``tuple[X, ...]``, ``list[X]`` or
    ``Sequence[X]`` annotation whose X is a dataclass or a Union of them; () for any other."""
    origin = typing.get_origin(hint)
    if origin is Union:  # Optional[tuple[...]]
        inner = [a for a in typing.get_args(hint) if a is not type(None)]
        return _dataclasses_in(inner[0]) if len(inner) == 1 else ()
    if origin not in (tuple, list, collections.abc.Sequence):
        return ()
    args = [a for a in typing.get_args(hint) if a is not Ellipsis]
    if len(args) != 1:
        return ()
    item = args[0]
    options = typing.get_args(item) if typing.get_origin(item) is Union else (item,)
    if options and all(dataclasses.is_dataclass(a) and isinstance(a, type) for a in options):
        return tuple(options)
    return ()


def _build_item(options: tuple[type, ...], value: Mapping[str, Any], name: str) -> Any:
    """One item of a sequence of dataclasses from its dict: the class its ``_target_`` names (one
    of ``options`` or a subclass), or the only option."""
    target = value.get("_target_")
    if target is None:
        if len(options) > 1:
            names = ", ".join(target_of(o) for o in options)
            raise ValueError(f"{name}: say which kind with _target_ (one of {names})")
        return build_dataclass(options[0], value, name)
    named = get_class(target)
    for option in options:
        if isinstance(named, type) and issubclass(named, option):
            return build_dataclass(option, value, name)
    names = ", ".join(target_of(o) for o in options)
    raise TypeError(f"{_key(name, '_target_')} must name one of {names}, got {target!r}")


def _key(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def build_dataclass(cls: type, values: Mapping[str, Any], name: str = "") -> Any:
    """``cls(**values)`` with nested dataclasses built from their dicts, after checking the keys
    and the value types.

    Args:
        cls: a dataclass (a ``_target_`` in ``values`` must name it or a subclass of it).
        values: plain Python values (a resolved config node).
        name: the config key of ``values``, for the messages ("" at the top).
    Raises:
        ValueError: an unknown key, ``"<key>: unknown setting (<cls> has: a, b, ...)"``; a missing
            required one, ``"<key> must be set"``.
        TypeError: a value of the wrong type (``check_field_types``'s message).
    """
    values = dict(values)
    target = values.pop("_target_", None)
    if target is not None:
        named = get_class(target)
        if not (isinstance(named, type) and issubclass(named, cls)):
            raise TypeError(f"{_key(name, '_target_')} must name {cls.__module__}.{cls.__qualname__}, got {target!r}")
        cls = named
    for extra in ("_partial_", "_recursive_", "_convert_"):
        values.pop(extra, None)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in values if k not in fields]
    if unknown:
        raise ValueError(f"{_key(name, unknown[0])}: unknown setting ({cls.__name__} has: {', '.join(fields)})")
    hints = typing.get_type_hints(cls)
    for field_name, value in list(values.items()):
        nested = _dataclass_of(hints.get(field_name))
        if nested is not None and isinstance(value, Mapping):
            values[field_name] = build_dataclass(nested, value, _key(name, field_name))
        options = _dataclasses_in(hints.get(field_name))
        if options and isinstance(value, (list, tuple)):
            values[field_name] = tuple(_build_item(options, v, f"{_key(name, field_name)}[{i}]")
                                       if isinstance(v, Mapping) else v for i, v in enumerate(value))
    check_field_types(cls, {k: v for k, v in values.items() if _dataclass_of(hints.get(k)) is None}, name)
    for f in fields.values():
        if f.name not in values and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ValueError(f"{_key(name, f.name)} must be set")
    try:
        return cls(**values)
    except (TypeError, ValueError) as err:  # a __post_init__ check names its field: name its key
        text = str(err)
        if name and text.split(" ", 1)[0] in fields:
            raise type(err)(f"{name}.{text}") from None
        raise


def build_settings(cfg: DictConfig | Mapping[str, Any]) -> Any:
    """The typed settings of a composed command config: its top-level ``_target_`` dataclass built
    from every key but ``hydra`` (``build_dataclass``). Interpolations are resolved and ``???``
    (a required value left unset) raises omegaconf's MissingMandatoryValue naming the key."""
    if isinstance(cfg, DictConfig):
        # Resolved key by key in place: a copy would lose the config's resolver cache, and a second
        # ${now:...} could name another second than hydra's run folder did.
        plain = {}
        for key in cfg.keys():
            if key != "hydra":
                value = cfg[key]  # resolved through the root and its cache; ??? raises, naming the key
                plain[key] = (OmegaConf.to_container(value, resolve=True, throw_on_missing=True)
                              if OmegaConf.is_config(value) else value)
    else:
        plain = {k: v for k, v in cfg.items() if k != "hydra"}
    if "_target_" not in plain:
        raise ValueError("the config has no _target_ naming its settings dataclass")
    return build_dataclass(object_type(plain["_target_"]), plain)


def target_of(cls: type) -> str:
    """The shortest importable dotted name of a class (``renderer.TraceSettings`` rather than
    ``renderer.settings.TraceSettings``), as a ``_target_``."""
    parts = cls.__module__.split(".")
    for i in range(1, len(parts) + 1):
        module = ".".join(parts[:i])
        try:
            if getattr(importlib.import_module(module), cls.__name__, None) is cls:
                return f"{module}.{cls.__name__}"
        except ImportError:
            continue
    return f"{cls.__module__}.{cls.__qualname__}"


def settings_record(settings: Any) -> Any:
    """Settings as the plain config they are built from (``build_settings`` builds them back):
    dataclasses become dicts with their ``_target_``, components stay as they are. What a run
    writes as its ``config.yaml``."""
    if dataclasses.is_dataclass(settings) and not isinstance(settings, type):
        record = {"_target_": target_of(type(settings))}
        for f in dataclasses.fields(settings):
            record[f.name] = settings_record(getattr(settings, f.name))
        return record
    if isinstance(settings, Mapping):
        return {k: settings_record(v) for k, v in settings.items()}
    if isinstance(settings, (list, tuple)):
        return [settings_record(v) for v in settings]
    return settings


def object_type(target: str) -> type:
    """The class a ``_target_`` names (a settings dataclass)."""
    cls = get_class(target)
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"_target_ must name a dataclass of settings, got {target!r}")
    return cls


__all__ = ["Component", "PathSettings", "build_dataclass", "build_settings", "object_type", "settings_record", "target_of"]
