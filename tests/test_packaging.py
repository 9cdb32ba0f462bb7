"""The package as a user installs it (``pip install .``, not editable): every module and every
config is in the wheel, and the console scripts, installed from it and run outside the checkout,
find their configs and print their help."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ("sdfdiff-train", "sdfdiff-evaluate", "sdfdiff-infer", "sdfdiff-mvr", "sdfdiff-build")


def _declared_packages() -> list[str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]


def test_every_package_of_the_tree_is_declared():
    """pyproject.toml names its packages one by one (configs/ ships as sdfdiff_configs): a new
    package folder must be added there, or a non-editable install would lack it."""
    tree = {".".join(p.parent.relative_to(ROOT).parts) for top in ("renderer", "sdfcommon", "mvr", "svr")
            for p in (ROOT / top).rglob("__init__.py")}
    declared = set(_declared_packages())
    assert tree | {"sdfdiff_configs"} == declared


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel of a clean copy of the source (a build/ folder left in the checkout by an earlier
    build could hold modules that no longer exist)."""
    source = tmp_path_factory.mktemp("source") / "sdfdiff"
    anywhere = shutil.ignore_patterns(".git", ".venv", "*.egg-info", "outputs", "multirun", "cache", "__pycache__",
                                      "docs", "tests")

    def ignore(folder: str, names: list[str]) -> set[str]:  # build/ at the top only: svr/data/build is a package
        skipped = set(anywhere(folder, names))
        if Path(folder) == ROOT and "build" in names:
            skipped.add("build")
        return skipped

    shutil.copytree(ROOT, source, ignore=ignore)
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                    str(source)], check=True, capture_output=True, text=True, timeout=600)
    (found,) = out.glob("sdfdiff-*.whl")
    return found


def test_the_wheel_holds_every_module_and_config(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    modules = {p.relative_to(ROOT).as_posix() for top in ("renderer", "sdfcommon", "mvr", "svr")
               for p in (ROOT / top).rglob("*.py")}
    configs = {"sdfdiff_configs/" + p.relative_to(ROOT / "configs").as_posix() for p in (ROOT / "configs").rglob("*.yaml")}
    assert modules and configs
    assert not modules - names, f"modules missing from the wheel: {sorted(modules - names)}"
    assert not configs - names, f"configs missing from the wheel: {sorted(configs - names)}"


def test_installed_console_scripts_print_their_help_outside_the_checkout(wheel, tmp_path):
    """Installed from the wheel (into a folder of its own, ahead of the editable install on the
    path), each console script runs from a folder outside the checkout and prints its help."""
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target), str(wheel)],
                   check=True, capture_output=True, text=True, timeout=600)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(target)}
    running = {script: subprocess.Popen([sys.executable, str(target / "bin" / script), "--help"], cwd=elsewhere,
                                        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for script in SCRIPTS}  # at once: each is a start-up (imports) of a few seconds
    for script, process in running.items():
        stdout, stderr = process.communicate(timeout=300)
        assert process.returncode == 0, f"{script}: {stderr[-2000:]}"
        assert script in stdout, stdout[-2000:]
    probe = subprocess.run([sys.executable, "-c", "import sdfdiff_configs, svr; print(sdfdiff_configs.__file__, "
                            "svr.__file__)"], cwd=elsewhere, env=env, capture_output=True, text=True, timeout=120)
    assert probe.stdout.split() == [str(target / "sdfdiff_configs" / "__init__.py"), str(target / "svr" / "__init__.py")]
    assert not list(elsewhere.iterdir())  # --help writes nothing
