"""Every benchmark is a leaf (benchmarks/__init__.py): a module of benchmarks/ imports the library
packages and the one shared helper module, ``benchmarks.common``, never another benchmark, not even
inside a function. ``benchmark_imports`` parses every ``benchmarks/*.py`` below a root with ``ast``
and lists the imports that break the rule; the test runs it on this repository, and on a tmp tree
with violations planted, to show that it finds each kind."""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGE = "benchmarks"
HELPER = "common"  # benchmarks.common: what several benchmarks share


def _imported(node: ast.AST) -> list[str]:
    """The absolute dotted names an import statement brings in (``from a import b`` gives ``a.b``:
    ``b`` may be a module); a relative import is resolved within the flat package."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom):
        base = ".".join(p for p in (PACKAGE if node.level == 1 else "", node.module or "") if p)
        return [f"{base}.{alias.name}" if base else alias.name for alias in node.names]
    return []


def benchmark_imports(root: Path) -> list[str]:
    """``<file>:<line>: imports benchmarks.<name>`` for every import, at any depth, in
    ``root/benchmarks/*.py`` of a benchmarks module other than the helper module."""
    found = set()
    for path in sorted((root / PACKAGE).glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            for name in _imported(node):
                parts = name.split(".")
                if parts[0] == PACKAGE and len(parts) > 1 and parts[1] != HELPER:
                    found.add((path.relative_to(root).as_posix(), node.lineno, f"{PACKAGE}.{parts[1]}"))
    return [f"{file}:{line}: imports {module}" for file, line, module in sorted(found)]


def test_every_benchmark_is_a_leaf():
    assert (REPO / PACKAGE / f"{HELPER}.py").is_file()
    assert benchmark_imports(REPO) == []


def test_a_planted_violation_is_caught(tmp_path):
    files = {
        "__init__.py": '"""The package."""\n',
        "common.py": "import svr\nfrom renderer import render\n",
        "good.py": "import benchmarks.common\nfrom benchmarks.common import Point\nfrom benchmarks import common\n"
                   "from . import common as c\nfrom .common import timed\nimport mvr\n",
        "top.py": "from benchmarks.good import x\n",
        "nested.py": "def run():\n    import benchmarks.good as g\n    return g\n",
        "sibling.py": "from benchmarks import good, common\n",
        "relative.py": "class A:\n    def f(self):\n        from .good import y\n        from . import top\n",
    }
    (tmp_path / PACKAGE).mkdir()
    for name, text in files.items():
        (tmp_path / PACKAGE / name).write_text(text)
    (tmp_path / "tests").mkdir()  # only benchmarks/*.py count
    (tmp_path / "tests" / "test_x.py").write_text("from benchmarks.good import x\n")
    assert benchmark_imports(tmp_path) == [
        "benchmarks/nested.py:2: imports benchmarks.good",
        "benchmarks/relative.py:3: imports benchmarks.good",
        "benchmarks/relative.py:4: imports benchmarks.top",
        "benchmarks/sibling.py:1: imports benchmarks.good",
        "benchmarks/top.py:1: imports benchmarks.good",
    ]
