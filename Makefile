# ProcTex: `make demo` and `make test` bootstrap everything on a fresh machine.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.proctex-installed
# torch first, pinned: 2.13.0 is the local CPU wheel (a newer one pulls gigabytes of CUDA packages).
TORCH  := torch==2.13.0

.PHONY: setup demo test test-fast gallery clean

# The Khronos glTF validator (npm) goes into the venv too; GLB tests use it where npm exists.
$(STAMP): pyproject.toml Makefile
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "ProcTex needs Python >= 3.11")'
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet $(TORCH)
	$(PY) -m pip install --quiet -e ".[dev,viz,embree,diffusion]"
	if command -v npm >/dev/null 2>&1; then npm install --silent --no-audit --no-fund --prefix $(VENV)/node gltf-validator@2.0.0-dev.3.10; fi
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(VENV)/bin/proctex demo --out out/demo

test: setup
	$(PY) -m pytest -q

test-fast: setup
	$(PY) -m pytest -q -m "not slow"

gallery: setup
	$(VENV)/bin/proctex gallery --out out/gallery

clean:
	rm -rf out .pytest_cache
