"""Imports flow one way (HOUSE_STYLE.md, Boundaries): renderer <- sdfcommon <- svr, mvr <-
benchmarks. Every .py file of the packages is parsed (imports at any depth, inside functions too),
the package import graph is built and printed (``pytest -s tests/test_layering.py`` shows it), and
the test fails when a package imports one above it or beside it, when two packages import each
other, when code outside ``renderer/`` reaches into a renderer submodule instead of the renderer's
public API, or when files of one package import each other in a cycle (the file graph, searched by
Tarjan's algorithm). Inside ``svr/`` its sub-packages are layered too (``SVR_LAYERS``): a
sub-package imports only those of lower layers.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("renderer", "sdfcommon", "svr", "mvr", "benchmarks")
# Which of our packages each package may import (what is not listed is forbidden).
ALLOWED = {
    "renderer": set(),
    "sdfcommon": {"renderer"},
    "svr": {"renderer", "sdfcommon"},
    "mvr": {"renderer", "sdfcommon"},
    "benchmarks": {"renderer", "sdfcommon", "svr", "mvr"},
}
# svr's sub-packages and top-level modules, lowest first: the benchmark's own definitions (NMR format,
# voxel frame, IoU) and the process group; the data; the losses; the networks (with the stage names
# and checkpoint key their checkpoints carry); loading and running them; training and evaluation; the
# demo's scoring workflow; the commands. Each may import only what lies in the layers before its own.
SVR_LAYERS = (
    ("nmr", "distributed"),
    ("data",),
    ("losses",),
    ("models",),
    ("inference",),
    ("training", "evaluation"),
    ("scoring",),
    ("train", "evaluate", "infer", "demo"),
)
# The renderer is a library of torch, numpy and numba: never the applications' frameworks.
RENDERER_NEVER = ("hydra", "omegaconf", "pytorch_lightning", "lightning")


@dataclass(frozen=True)
class Import:
    """One reference of a file to a module of ours: ``module`` is the absolute dotted name imported
    (``from a.b import c`` gives ``a.b`` with ``names=("c",)``; ``import a.b`` gives ``a.b``)."""

    file: str
    line: int
    module: str
    names: tuple[str, ...] = ()
    attribute: bool = False  # ``renderer.<name>`` in code, not an import statement


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _resolve(node: ast.ImportFrom, module: str, is_package: bool) -> Optional[str]:
    """The absolute module of a (possibly relative) ``from ... import``."""
    if node.level == 0:
        return node.module
    base = module.split(".") if is_package else module.split(".")[:-1]
    if node.level > 1:
        base = base[:len(base) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])]) or None


def imports_of(path: Path, root: Path = REPO) -> Iterator[Import]:
    """Every import of one of ``PACKAGES`` in the file at ``path``, also those inside functions,
    and every ``renderer.<name>`` in the code (as ``Import(module="renderer", names=(name,),
    attribute=True)``: after ``import renderer``, ``renderer.kernels.available(...)`` reaches into a
    submodule as an import would)."""
    source = path.read_text(encoding="utf-8")
    tree = ast.parse(source, filename=str(path))
    module = _module_name(path, root)
    rel = path.relative_to(root).as_posix()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in PACKAGES:
                    yield Import(rel, node.lineno, alias.name)
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(node, module, path.name == "__init__.py")
            if target and target.split(".")[0] in PACKAGES:
                yield Import(rel, node.lineno, target, tuple(a.name for a in node.names))
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "renderer":
            yield Import(rel, node.lineno, "renderer", (node.attr,), attribute=True)


def _files(root: Path) -> Iterator[Path]:
    for package in PACKAGES:
        yield from sorted((root / package).rglob("*.py"))


def renderer_public_names(root: Path = REPO) -> set[str]:
    """``renderer.__all__``, read from the source (no import)."""
    tree = ast.parse((root / "renderer" / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            return set(ast.literal_eval(node.value))
    raise AssertionError("renderer/__init__.py has no literal __all__")


def import_graph(root: Path = REPO) -> dict[str, dict[str, list[Import]]]:
    """{package: {imported package: [imports]}} over the files of ``PACKAGES`` under ``root``
    (a package's imports of itself left out)."""
    graph: dict[str, dict[str, list[Import]]] = {p: {} for p in PACKAGES}
    for path in _files(root):
        package = path.relative_to(root).parts[0]
        for imp in imports_of(path, root):
            target = imp.module.split(".")[0]
            if target != package and not imp.attribute:
                graph[package].setdefault(target, []).append(imp)
    return graph


def violations(root: Path = REPO) -> list[str]:
    """What breaks the one-way rule, one line each (empty when the layering holds)."""
    graph = import_graph(root)
    public = renderer_public_names(root)
    out = []
    for package, targets in graph.items():
        for target, imps in sorted(targets.items()):
            if target not in ALLOWED[package]:
                out += [f"{i.file}:{i.line}: {package} imports {i.module} ({package} may import "
                        f"{sorted(ALLOWED[package]) or 'nothing of ours'})" for i in imps]
    for package in PACKAGES:
        for target in graph[package]:
            if package < target and package in graph.get(target, {}):
                out.append(f"{package} and {target} import each other")
    for path in sorted((root / "renderer").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module else [])
            out += [f"{path.relative_to(root).as_posix()}:{node.lineno}: renderer imports {name}"
                    for name in names if name.split(".")[0] in RENDERER_NEVER]
    for path in _files(root):
        if path.relative_to(root).parts[0] == "renderer":
            continue
        for imp in imports_of(path, root):
            if imp.module.split(".")[0] != "renderer":
                continue
            private = imp.module != "renderer" or not set(imp.names) <= public
            if private:
                what = imp.module + (f" ({', '.join(imp.names)})" if imp.names else "")
                out.append(f"{imp.file}:{imp.line}: reaches into the renderer: {what}; use renderer's "
                           f"public API (renderer.__all__)")
    return out


def _svr_unit(module: str) -> Optional[str]:
    """The sub-package or top-level module of svr that ``module`` belongs to (None for ``svr`` itself)."""
    parts = module.split(".")
    return parts[1] if parts[0] == "svr" and len(parts) > 1 else None


def svr_violations(root: Path = REPO) -> list[str]:
    """Imports inside ``svr/`` against ``SVR_LAYERS``, one line each; a file of svr outside every
    layer is named too, so a new sub-package must be given its place."""
    layer = {unit: i for i, units in enumerate(SVR_LAYERS) for unit in units}
    out = []
    for path in sorted((root / "svr").rglob("*.py")):
        module = _module_name(path, root)
        unit = _svr_unit(module)
        if unit is None:
            continue
        if unit not in layer:
            out.append(f"{path.relative_to(root).as_posix()}: svr.{unit} is in no layer of SVR_LAYERS")
            continue
        for imp in imports_of(path, root):
            target = _svr_unit(imp.module)
            if imp.attribute or target is None or target == unit:
                continue
            if target not in layer or layer[target] >= layer[unit]:
                allowed = sorted(u for u, i in layer.items() if i < layer[unit])
                out.append(f"{imp.file}:{imp.line}: svr.{unit} imports {imp.module} (svr.{unit} may import "
                           f"{', '.join('svr.' + u for u in allowed) or 'nothing of svr'})")
    return out


def format_graph(graph: dict[str, dict[str, list[Import]]]) -> str:
    lines = ["package import graph (package -> what it imports, with the number of imports):"]
    for package in PACKAGES:
        targets = ", ".join(f"{t} ({len(graph[package][t])})" for t in PACKAGES if t in graph[package])
        lines.append(f"  {package:<10} -> {targets or '(nothing of ours)'}")
    return "\n".join(lines)


def test_imports_flow_one_way():
    print("\n" + format_graph(import_graph()))
    found = violations()
    assert not found, "imports against the layering:\n" + "\n".join(found)


def test_svr_sub_packages_import_downwards_only():
    found = svr_violations()
    assert not found, "imports against svr's layers (SVR_LAYERS):\n" + "\n".join(found)


def test_the_svr_check_catches_an_upward_import(tmp_path):
    """An upward import (the data importing the evaluation), one between the two halves of a layer,
    one inside a function and a module in no layer are each refused; downward imports pass."""
    files = {
        "svr/__init__.py": "",
        "svr/nmr/__init__.py": "",
        "svr/nmr/voxels.py": "import numpy\n",
        "svr/data/__init__.py": "",
        "svr/data/gen.py": "from svr.nmr.voxels import x\nfrom svr.evaluation.tables import t\n",
        "svr/models/module.py": "from svr.data import gen\ndef f():\n    from svr.inference import checkpoints\n",
        "svr/training/stages.py": "from svr.evaluation import protocol\nfrom svr.models import module\n",
        "svr/evaluation/tables.py": "from svr.inference.prediction import load_model\n",
        "svr/extras.py": "",
        "svr/demo.py": "from svr.training.stages import train\nfrom svr.evaluation.tables import t\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    found = svr_violations(tmp_path)
    text = "\n".join(found)
    assert "svr/data/gen.py:2: svr.data imports svr.evaluation.tables" in text
    assert "svr/models/module.py:3: svr.models imports svr.inference" in text
    assert "svr/training/stages.py:1: svr.training imports svr.evaluation" in text
    assert "svr/extras.py: svr.extras is in no layer of SVR_LAYERS" in text
    assert len(found) == 4, found  # the downward imports (nmr, data, models, training, inference) pass


def test_the_check_catches_each_kind_of_violation(tmp_path):
    """A tree with one violation of each kind is refused, each named, so the test above can fail."""
    files = {
        "renderer/__init__.py": '__all__ = ["render", "SDFGrid"]\n',
        "renderer/grid.py": "def f():\n    import svr\n",  # the renderer imports an application
        "renderer/scene.py": "from omegaconf import DictConfig\n",
        "sdfcommon/__init__.py": "",
        "sdfcommon/x.py": "from mvr import y\n",  # the shared layer imports an application
        "svr/__init__.py": "",
        "svr/a.py": ("import renderer\nfrom renderer import render\nfrom renderer.shading import shade\n"
                     "def g():\n    from mvr.b import c\n    return renderer.kernels.available('cpu')\n"),
        "mvr/__init__.py": "",
        "mvr/b.py": "from svr import a\nfrom renderer import SDFGrid, secret\n",
        "benchmarks/__init__.py": "",
        "benchmarks/z.py": "from svr import a\nfrom mvr import b\n",  # allowed
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    found = "\n".join(violations(tmp_path))
    assert "renderer/grid.py:2: renderer imports svr" in found
    assert "renderer/scene.py:1: renderer imports omegaconf" in found
    assert "sdfcommon/x.py:1: sdfcommon imports mvr" in found
    assert "svr/a.py:5: svr imports mvr.b" in found and "mvr/b.py:1: mvr imports svr" in found
    assert "mvr and svr import each other" in found
    assert "svr/a.py:3: reaches into the renderer: renderer.shading (shade)" in found
    assert "svr/a.py:6: reaches into the renderer: renderer (kernels)" in found
    assert "mvr/b.py:2: reaches into the renderer: renderer (SDFGrid, secret)" in found
    assert "benchmarks" not in found and "svr/a.py:1:" not in found and "svr/a.py:2:" not in found


# ------------------------------------------------------------------------------------------------
# Import cycles between the files of one package

def module_graph(root: Path = REPO) -> dict[str, dict[str, list[Import]]]:
    """{module: {module of the same package it imports: [imports]}} over the files of ``PACKAGES``.

    ``import a.b`` and ``from a.b import c`` import the module ``a.b`` (its parents' ``__init__``
    are not counted), except that ``from a.b import c`` imports the module ``a.b.c`` when there is
    one. Imports inside functions count: they run, only later.
    """
    modules = {_module_name(p, root): p for p in _files(root)}
    graph: dict[str, dict[str, list[Import]]] = {m: {} for m in modules}
    for module, path in modules.items():
        for imp in imports_of(path, root):
            if imp.attribute or imp.module.split(".")[0] != module.split(".")[0]:
                continue
            targets = {f"{imp.module}.{n}" if f"{imp.module}.{n}" in modules else imp.module for n in imp.names}
            for target in targets or {imp.module}:
                if target in modules and target != module:
                    graph[module].setdefault(target, []).append(imp)
    return graph


def strongly_connected(graph: dict[str, dict[str, list[Import]]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm,
    iterative), each sorted, in sorted order: every import cycle lies inside one of them."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            for succ in successors:
                if succ not in index:
                    index[succ] = low[succ] = len(index)
                    stack.append(succ)
                    on_stack.add(succ)
                    work.append((succ, iter(sorted(graph[succ]))))
                    break
                if succ in on_stack:
                    low[node] = min(low[node], index[succ])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return sorted(out)


def file_cycles(root: Path = REPO) -> dict[tuple[str, ...], str]:
    """{modules of a group of files that import each other (sorted): one line round a cycle of
    the group, with the line of each import}, e.g. ``svr.a -> svr.b (svr/a.py:3) -> svr.a (svr/b.py:1)``."""
    graph = module_graph(root)
    out = {}
    for component in strongly_connected(graph):
        members = set(component)
        # A shortest way back to the first module, through the component only (breadth first).
        first = component[0]
        previous: dict[str, str] = {}
        frontier = [first]
        while frontier and first not in previous:
            nxt = []
            for node in frontier:
                for succ in sorted(graph[node]):
                    if succ in members and succ not in previous:
                        previous[succ] = node
                        nxt.append(succ)
            frontier = nxt
        path = [first]
        while len(path) == 1 or path[-1] != first:
            path.append(previous[path[-1]])
        path.reverse()
        steps = [f"{b} ({graph[a][b][0].file}:{graph[a][b][0].line})" for a, b in zip(path, path[1:])]
        out[tuple(component)] = " -> ".join([first, *steps]) + (
            f"; all of {', '.join(component)}" if len(component) > 2 else "")
    return out


def test_no_import_cycles_between_the_files_of_a_package():
    found = file_cycles()
    print("\nimport cycles between files:" + "".join(f"\n  {line}" for line in found.values()) if found else "")
    assert not found, "files that import each other (move what both need below both):\n" + "\n".join(found.values())


def test_the_cycle_check_finds_a_known_cycle_and_passes_an_acyclic_tree(tmp_path):
    cyclic = {
        "svr/__init__.py": "",
        "svr/a.py": "from svr.b import f\n",
        "svr/b.py": "import os\n\ndef f():\n    from svr import c\n",  # inside a function: counts
        "svr/c.py": "from . import a\n",  # relative, names the module a
        "svr/pkg/__init__.py": "from svr.pkg.d import x\n",
        "svr/pkg/d.py": "from svr.pkg import y\n",  # y is no module: imports svr/pkg/__init__
        "mvr/__init__.py": "",
        "mvr/e.py": "from svr import a\n",  # across packages: the layering test's business
    }
    acyclic = {
        "svr/__init__.py": "",
        "svr/a.py": "from svr.b import f\nimport svr.c\n",
        "svr/b.py": "from svr import c\n",
        "svr/c.py": "import svr\n",  # the package's __init__, which imports nothing
        "svr/pkg/__init__.py": "from svr.pkg.d import x\n",
        "svr/pkg/d.py": "from svr import a\n",
    }
    for name, files in (("cyclic", cyclic), ("acyclic", acyclic)):
        for rel, text in files.items():
            (tmp_path / name / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name / rel).write_text(text)
    assert file_cycles(tmp_path / "cyclic") == {
        ("svr.a", "svr.b", "svr.c"):
            "svr.a -> svr.b (svr/a.py:1) -> svr.c (svr/b.py:4) -> svr.a (svr/c.py:1); all of svr.a, svr.b, svr.c",
        ("svr.pkg", "svr.pkg.d"): "svr.pkg -> svr.pkg.d (svr/pkg/__init__.py:1) -> svr.pkg (svr/pkg/d.py:1)",
    }
    assert file_cycles(tmp_path / "acyclic") == {}
