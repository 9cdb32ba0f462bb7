"""sdfcommon.tooling.settings: typed settings from configs refuse unknown keys and mistyped values
(naming the key), build nested dataclasses, keep components as plain dicts, and turn back into the
config they came from; every command's YAML builds its settings."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional

import pytest
import torch
from omegaconf import OmegaConf

from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import Component, build_dataclass, build_settings, settings_record


@dataclass(frozen=True)
class Inner:
    lr: float
    steps: int = 3

    def __post_init__(self) -> None:
        if not self.lr > 0:
            raise ValueError(f"lr must be positive, got {self.lr!r}")


@dataclass(frozen=True)
class Outer:
    name: str
    inner: Inner
    sizes: list[int]
    part: Optional[Component] = None


TARGET = f"{__name__}.Outer"


def test_builds_nested_dataclasses_and_keeps_components():
    cfg = OmegaConf.create({"_target_": TARGET, "name": "a", "inner": {"lr": 0.5}, "sizes": [1, 2],
                            "part": {"_target_": "torch.nn.Identity"}, "hydra": {"ignored": True}})
    settings = build_settings(cfg)
    assert settings == Outer("a", Inner(0.5), [1, 2], {"_target_": "torch.nn.Identity"})
    assert isinstance(settings.part, dict)


@pytest.mark.parametrize("values, error, message", [
    ({"nope": 1}, ValueError, "nope: unknown setting (Outer has: name, inner, sizes, part)"),
    ({"inner": {"lr": 0.5, "nope": 1}}, ValueError, "inner.nope: unknown setting (Inner has: lr, steps)"),
    ({"name": 3}, TypeError, "name must be a string, got 3"),
    ({"inner": {"lr": "fast"}}, TypeError, "inner.lr must be a number, got 'fast'"),
    ({"inner": {"lr": 0.5, "steps": 2.5}}, TypeError, "inner.steps must be an integer, got 2.5"),
    ({"sizes": ["a"]}, TypeError, "sizes must be a list of (an integer), got ['a']"),
    ({"inner": {"lr": -1.0}}, ValueError, "inner.lr must be positive, got -1.0"),  # __post_init__, named by key
    ({"inner": {"steps": 1}}, ValueError, "inner.lr must be set"),
])
def test_refuses_unknown_keys_and_wrong_values_naming_the_key(values, error, message):
    good = {"name": "a", "inner": {"lr": 0.5}, "sizes": [1]}
    merged = {**good, **values}
    if "inner" in values:
        merged["inner"] = values["inner"]
    with pytest.raises(error) as err:
        build_dataclass(Outer, merged)
    assert str(err.value) == message


def test_a_target_must_name_the_expected_class_and_a_dataclass():
    with pytest.raises(TypeError, match="inner._target_ must name"):
        build_dataclass(Outer, {"name": "a", "sizes": [], "inner": {"_target_": TARGET, "lr": 1.0}})
    with pytest.raises(TypeError, match="_target_ must name a dataclass"):
        build_settings({"_target_": "torch.nn.Identity"})
    with pytest.raises(ValueError, match="no _target_"):
        build_settings({"name": "a"})


def test_the_record_builds_the_same_settings_back():
    settings = Outer("a", Inner(0.5, 4), [1, 2], {"_target_": "torch.nn.Identity", "x": [1]})
    record = settings_record(settings)
    assert record == {"_target_": TARGET, "name": "a", "inner": {"_target_": f"{__name__}.Inner", "lr": 0.5, "steps": 4},
                      "sizes": [1, 2], "part": {"_target_": "torch.nn.Identity", "x": [1]}}
    assert build_settings(record) == settings


@pytest.mark.parametrize("name, overrides", [
    ("train", []), ("train", ["experiment=demo"]),
    # paper_nmr chooses trainer=gpu, which a machine without a GPU refuses (tests/test_cli.py)
    ("train", ["experiment=paper_nmr", "data.root=/x", *([] if torch.cuda.is_available() else ["trainer=cpu"])]),
    ("demo", []), ("eval", ["ckpt_path=x.ckpt"]), ("infer", ["ckpt_path=x.ckpt", "images=a.png"]),
    ("mvr", ["target=torus"]),
])
def test_every_commands_yaml_builds_its_settings_and_refuses_an_unknown_key(name, overrides):
    settings = build_settings(compose(name, overrides))
    assert dataclasses.is_dataclass(settings) and build_settings(settings_record(settings)) == settings
    with pytest.raises(ValueError, match="nonsense: unknown setting"):
        build_settings(compose(name, [*overrides, "+nonsense=1"]))


@dataclass(frozen=True)
class Folders:
    paths: dict
    out: str


def test_a_time_stamp_resolves_as_it_did_for_the_run_folder():
    """Settings built after hydra resolved the run folder give the same ${now:...}, also inside a
    node (a copy of the config would resolve it afresh, possibly a second later)."""
    ticks = iter(range(100))
    OmegaConf.register_new_resolver("tick", lambda: next(ticks), use_cache=True, replace=True)
    cfg = OmegaConf.create({"_target_": f"{__name__}.Folders", "paths": {"out": "o/${tick:}"}, "out": "${paths.out}/x",
                            "hydra": {"run": {"dir": "${paths.out}"}}})
    run_dir = cfg.hydra.run.dir
    next(ticks)  # a later resolution would see another value
    settings = build_settings(cfg)
    assert run_dir == "o/0" and settings == Folders({"out": "o/0"}, "o/0/x")


def test_a_list_of_dataclasses_is_built_item_by_item_each_named_by_its_target():
    """configs/mvr.yaml's ``scene.lights``: every item a light built from its dict, the kind named by
    its ``_target_``; the record builds the same settings back; mistakes name the item."""
    lights = ("scene.lights=[{_target_:renderer.DirectionalLight,direction:[1,1,1],intensity:0.25},"
              "{_target_:renderer.PointLight,position:[0,2,0],falloff:false}]")
    settings = build_settings(compose("mvr", ["target=torus", lights]))
    from renderer import DirectionalLight, PointLight
    assert settings.scene.lights == (DirectionalLight((1.0, 1.0, 1.0), 0.25), PointLight((0.0, 2.0, 0.0), 1.0, False))
    assert build_settings(settings_record(settings)) == settings
    for items, error, message in [
        ("[{direction:[1,1,1]}]", ValueError, "scene.lights[0]: say which kind with _target_ (one of "
                                              "renderer.DirectionalLight, renderer.PointLight)"),
        ("[{_target_:renderer.Scene}]", TypeError, "scene.lights[0]._target_ must name one of "
                                                   "renderer.DirectionalLight, renderer.PointLight, got 'renderer.Scene'"),
        ("[{_target_:renderer.PointLight,pos:[0,1,0]}]", ValueError,
         "scene.lights[0].pos: unknown setting (PointLight has: position, intensity, falloff)"),
    ]:
        with pytest.raises(error) as err:
            build_settings(compose("mvr", ["target=torus", f"scene.lights={items}"]))
        assert str(err.value) == message
