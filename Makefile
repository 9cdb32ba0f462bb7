# Set-up, tests and the demo. `make test` and `make demo` each create the virtual
# environment on first use, so a fresh clone needs nothing else.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
# A CPU build of torch is pinned on machines without an NVIDIA GPU; an unpinned
# torch would pull several GB of CUDA packages.
TORCH_CPU ?= torch==2.13.0
HAS_GPU := $(shell command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1 && echo 1)
# On a GPU host: the extra with numba-cuda for the driver's CUDA major version (nvidia-smi's
# "CUDA Version: 13.0" header), so the fused CUDA kernels build instead of the slow fallback.
CUDA_MAJOR := $(shell nvidia-smi 2>/dev/null | sed -n 's/.*CUDA Version: *\([0-9]*\).*/\1/p' | head -n 1)
CUDA_EXTRA := $(if $(filter 12,$(CUDA_MAJOR)),cuda12,cuda13)

.PHONY: install test test-slow demo bench clean

$(VENV)/.installed: pyproject.toml Makefile
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip wheel setuptools
ifeq ($(HAS_GPU),1)
	$(PIP) install "torch>=2.4"
	$(PIP) install -e ".[dev,$(CUDA_EXTRA)]"
	$(PY) -c 'import sys, renderer; ok, why = renderer.stage2_available("cuda"); print("fused CUDA kernels: ready" if ok else "WARNING: the fused CUDA kernels do not run here (" + why + "); renders on the GPU will use the slow PyTorch reference", file=sys.stderr)'
else
	$(PIP) install $(TORCH_CPU)
	$(PIP) install -e ".[dev]"
endif
	touch $@

install: $(VENV)/.installed

test: install
	$(PY) -m pytest -q

test-slow: install
	$(PY) -m pytest -q -m slow -n 0

# The main job: single-view training (experiment=demo) on the built-in procedural data, then the
# benchmark IoU table, pictures and meshes in outputs/demo/. Run again to resume a stopped run.
demo: install
	$(PY) -m svr.demo out=outputs/demo

bench: install
	$(PY) -m benchmarks.renderer_speed

clean:
	rm -rf $(VENV) outputs .pytest_cache
