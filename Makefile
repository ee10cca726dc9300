# ProcTex: `make demo` and `make test` bootstrap everything on a fresh machine.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.proctex-installed
# torch first, pinned: 2.13.0 is the local CPU wheel (a newer one pulls gigabytes of CUDA packages).
TORCH  := torch==2.13.0
# The web studio (served at / by the transfer service): npm project, bundled into $(STUDIO)/dist.
STUDIO     := workers/studio
STUDIO_OUT := $(STUDIO)/dist/index.html
STUDIO_SRC := $(STUDIO)/package.json $(STUDIO)/package-lock.json $(STUDIO)/build.mjs $(STUDIO)/index.html $(STUDIO)/style.css $(wildcard $(STUDIO)/src/*.js)

.PHONY: xatlas-single-threaded wheel image setup demo format test test-fast test-other-kernels float-margins bench bench-fidelity gallery clean studio browser blender blender-addon blender-fixtures docs

# Blender's Python (bpy, which needs numpy < 2) in an environment of its own, for .blend family
# sources (proctex/sources/blender.py). A machine where bpy cannot be installed skips those tests.
BLENDER_VENV := .venv-blender
BLENDER_STAMP := $(BLENDER_VENV)/.bpy-installed
$(BLENDER_STAMP):
	@($(PYTHON) -m venv $(BLENDER_VENV) && $(BLENDER_VENV)/bin/python -m pip install --quiet --upgrade pip \
	  && $(BLENDER_VENV)/bin/python -m pip install --quiet bpy==5.0.1 && touch $(BLENDER_STAMP)) \
	  || echo "bpy could not be installed: the Blender tests will skip"

blender: $(BLENDER_STAMP)

# The .blend files of the Blender tests (vase, table, pumpkin, rack, bench), built in code into out/blend.
blender-fixtures: $(BLENDER_STAMP)
	$(BLENDER_VENV)/bin/python tests/fixtures/blend/make_fixtures.py out/blend

# The Blender add-on (clients/blender): a legacy zip for Preferences > Add-ons > Install from Disk,
# and the Blender 4.2+ extension (blender_manifest.toml at its root) for Get Extensions > Install from Disk.
blender-addon:
	$(PYTHON) clients/blender/build_zip.py out/proctex_blender.zip
	$(PYTHON) clients/blender/build_zip.py --extension out/proctex_blender_extension.zip

# The Khronos glTF validator (npm) goes into the venv too; GLB tests use it where npm exists.
# Where npm exists, the studio's locked packages are installed (npm ci) and bundled too.
$(STAMP): pyproject.toml Makefile $(STUDIO)/package.json $(STUDIO)/package-lock.json
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "ProcTex needs Python >= 3.11")'
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet $(TORCH)
	$(PY) -m pip install --quiet -e ".[dev,viz,embree,diffusion]"
	$(MAKE) --no-print-directory xatlas-single-threaded
	if command -v npm >/dev/null 2>&1; then npm install --silent --no-audit --no-fund --prefix $(VENV)/node gltf-validator@2.0.0-dev.3.10; fi
	if command -v npm >/dev/null 2>&1; then npm ci --loglevel=error --no-audit --no-fund --prefix $(STUDIO) && npm run --silent --prefix $(STUDIO) build; \
	else echo "npm not found: the web studio is not built (the service's / page says so)"; fi
	touch $(STAMP)

# xatlas again, the same version, built from its source without threads (XA_MULTITHREADED=0): the
# wheel's task scheduler can hang for ever when an Atlas is destroyed (a lost wake-up in its
# destructor; proctex/texture/uv.py). Needs a C++ compiler and CMake; tests/test_uv_render.py checks the result.
xatlas-single-threaded:
	CMAKE_ARGS="-DCMAKE_CXX_FLAGS=-DXA_MULTITHREADED=0" $(PY) -m pip install --quiet --no-cache-dir --force-reinstall --no-deps \
	  --no-binary xatlas "xatlas==$$($(PY) -c "import importlib.metadata as m; print(m.version('xatlas'))")"

# Rebundle the studio when its sources change after setup.
$(STUDIO_OUT): $(STUDIO_SRC)
	if command -v npm >/dev/null 2>&1; then test -d $(STUDIO)/node_modules || npm ci --loglevel=error --no-audit --no-fund --prefix $(STUDIO); \
	npm run --silent --prefix $(STUDIO) build; fi

studio: $(STAMP) $(STUDIO_OUT)

setup: $(STAMP) $(STUDIO_OUT)

# Debian's Chromium for the studio's browser test (tests/test_studio.py; Playwright drives it, no browser download).
browser:
	@if command -v chromium >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; \
	elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; \
	else echo "chromium is missing and cannot be installed here (not root, no sudo): the studio browser test will skip"; fi

demo: setup
	$(VENV)/bin/proctex demo --out out/demo

# The whole suite, then the fast tests marked `numeric` (float results under a tolerance) a second
# time on other kernels than this CPU's own, one tier down (numpy's dispatch, OpenBLAS's core type,
# ATen, oneDNN, MKL: tests/portable.py other_env), so a threshold that holds only on this CPU's
# kernels fails here and not on a user's machine (issue 49).
# Both passes run in TEST_WORKERS processes (pytest-xdist), each test module whole in one of them
# (--dist loadfile: a module's fixtures are built once): much of the suite waits on processes it
# started. Three workers overload 2 cores: Ray gives a starting node 30 s (not configurable), and
# private Rays then failed to start. The second pass (compute only) runs beside the first at nice
# 10, on the cores the first leaves idle, and again at the normal priority if the machine had none
# (tests/suite.py). Bytecode is written (the tree's __pycache__ is ignored by git), so each worker
# does not compile every test module again.
TEST_WORKERS ?= 2
test: setup browser blender
	$(PY) -m tests.suite --workers $(TEST_WORKERS)

# The formatter and the linter over every Python folder ([tool.ruff] in pyproject.toml); `make
# test` checks both (tests/test_lint.py).
format: setup
	$(VENV)/bin/ruff format proctex workers workflows tests clients
	$(VENV)/bin/ruff check proctex workers workflows tests clients

# The wheel (dist/proctex-VERSION-py3-none-any.whl: the packages, the studio's bundle, the Blender
# server script) and the cluster image cluster/Dockerfile makes of it, tagged with the version the
# KubeRay manifests name (docker is needed for the image only).
VERSION = $(shell sed -n 's/^version = "\(.*\)"/\1/p' pyproject.toml)
wheel: setup
	rm -rf dist && $(PY) -m pip wheel --quiet --no-deps --no-build-isolation . -w dist

image: wheel
	docker build -f cluster/Dockerfile -t ghcr.io/proctex/proctex:$(VERSION) .

# The benchmark suite (not part of make test): JSON per benchmark and a summary table in out/bench.
bench: setup
	$(PY) tests/bench/run_all.py --out out/bench

# No family got worse (issue 52): rebuild the committed fidelity baseline's families at its seeds with
# today's code and compare; exits 1 when a family got worse beyond its noise. Hours on 2 cores for
# every family: FAMILIES=sofa,mushroom checks those only.
bench-fidelity: setup
	$(PY) tests/bench/fidelity_baseline.py --compare tests/bench/fidelity_baseline.json $(if $(FAMILIES),--families $(FAMILIES))

test-fast: setup
	$(PY) -m pytest -q -m "not slow"

# The whole suite on other kernels than this CPU's own (tests/portable.py other_env: on an AVX-512
# CPU an AVX2 machine's, on an AVX2 CPU the x86-64-v2 baseline and Sandybridge's BLAS).
test-other-kernels: setup browser blender
	$(PY) -m tests.portable -q

# How far every float check sits from its threshold: the fast tests natively, on other kernels and
# with both cores busy, then the checks whose margin is under 3x how far they moved (tests/float_margins.py).
float-margins: setup
	$(PY) -m tests.float_margins run --env native --out out/margins/native.jsonl
	$(PY) -m tests.float_margins run --env other --out out/margins/other.jsonl
	$(PY) -m tests.float_margins run --env native --load --out out/margins/load.jsonl
	$(PY) -m tests.float_margins report out/margins/native.jsonl out/margins/other.jsonl out/margins/load.jsonl --json out/margins/report.json

# The configuration reference, generated from the build config's dataclasses (workflows/docs.py);
# tests/test_docs.py fails when docs/configuration.md is not what this writes.
docs: setup
	$(PY) -m workflows.docs --out docs/configuration.md

gallery: setup
	$(VENV)/bin/proctex gallery --out out/gallery

clean:
	rm -rf out .pytest_cache $(STUDIO)/dist
