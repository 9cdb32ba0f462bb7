"""Every module of the five packages opens with a docstring of one paragraph (what the module is for
and holds, in prose; usage examples go to ``--help`` texts and background to docs/). The files are
parsed with ``ast``, never imported, and the test fails with the list of offenders: a module with no
docstring, an empty one, or one with a blank line inside. A self-test on a toy tree shows that the
check can fail.
"""
from __future__ import annotations

import ast
from pathlib import Path
from typing import Iterable

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("renderer", "sdfcommon", "svr", "mvr", "benchmarks")


def docstring_problem(source: str) -> str | None:
    """Why a module's source fails the rule ("no docstring", "empty docstring", "more than one
    paragraph"), or None when it passes."""
    doc = ast.get_docstring(ast.parse(source), clean=True)
    if doc is None:
        return "no docstring"
    if not doc.strip():
        return "empty docstring"
    lines = doc.strip().splitlines()
    if any(not line.strip() for line in lines):
        return "more than one paragraph"
    return None


def docstring_offenders(root: Path, packages: Iterable[str]) -> list[str]:
    """``"<path>: <problem>"`` for every .py file under ``root/<package>`` that fails the rule, paths
    relative to ``root`` with forward slashes, sorted."""
    out = []
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            problem = docstring_problem(path.read_text(encoding="utf-8"))
            if problem is not None:
                out.append(f"{rel}: {problem}")
    return out


def test_every_module_has_a_one_paragraph_docstring():
    offenders = docstring_offenders(REPO, PACKAGES)
    assert not offenders, "module docstrings must be one non-empty paragraph:\n" + "\n".join(offenders)


def test_the_check_names_offenders_in_a_toy_tree(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text('"""A package whose docstring is one paragraph,\nover two lines."""\n')
    (pkg / "two.py").write_text('"""First paragraph.\n\nSecond paragraph.\n"""\nX = 1\n')
    (pkg / "sub" / "none.py").write_text("X = 1\n")
    (pkg / "sub" / "empty.py").write_text('"""   """\n')
    (pkg / "sub" / "blank_with_spaces.py").write_text('"""First.\n    \n    Second.\n"""\n')
    (pkg / "sub" / "comment_first.py").write_text('# a comment, then the docstring\n"""One paragraph."""\n')

    assert docstring_offenders(tmp_path, ["pkg"]) == [
        "pkg/sub/blank_with_spaces.py: more than one paragraph",
        "pkg/sub/empty.py: empty docstring",
        "pkg/sub/none.py: no docstring",
        "pkg/two.py: more than one paragraph",
    ]
