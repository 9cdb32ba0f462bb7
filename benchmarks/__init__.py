"""Speed and accuracy-versus-time studies, each run from the repository root as
``python -m benchmarks.<name>`` (the package is not installed); each module's docstring and
``--help`` say what it measures and where its report goes (docs/README.md lists the reports).
Every benchmark is a leaf: it imports the library packages (renderer, sdfcommon, svr, mvr) and
``benchmarks.common``, what several benchmarks share, never another benchmark; one that needs
another's results runs it as a command (tests/benchmarks/test_leaves.py checks the imports).
"""
