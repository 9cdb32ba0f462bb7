"""Speed and accuracy-versus-time studies, each run from the repository root as
``python -m benchmarks.<name>`` (the package is not installed); each module's docstring and
``--help`` say what it measures and where its report goes (docs/README.md lists the reports).
"""
