# Two commands for a newcomer on a fresh machine:
#   make demo   set up .venv and run every estimator on the sample frames shipped in the package
#   make test   set up .venv (test extras, Dask, the CPU build of PyTorch, Open3D, the authors' d2nt) and run all tests:
#               make lint, make docs, the docstrings' and the documentation's examples, then pytest
#   make test-fast  the tests not marked slow (pytest -m "not slow"): every module under src/surfnorm runs (checked),
#               the naive references at small sizes; about a minute warm, for the loop of changing code (make test: all)
#   make lint   ruff (lint, docstrings, formatting) and mypy (the modules that are not Numba kernels)
#   make docs   the documentation site, warnings as errors -> site/index.html
#   make bench  speed of the D2NT family next to the authors' d2nt package -> bench-output/speed.{md,json}
#   make pictures  the documentation's pictures from the shipped frames -> docs/images/*.png
#               (OpenCV 5 for RgbdNormals; SENSOR_SAMPLE=DIR adds the sensor benchmark's figure)
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
TEST_STAMP := $(VENV)/.test-installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
# PyTorch for the tests of surfnorm.torch: the CPU build (on this machine pip finds its wheel file)
TORCH_VERSION := 2.13.0
TORCH_STAMP := $(VENV)/.torch-installed-$(TORCH_VERSION)
# Open3D for the tests of the PLY point clouds (tests/test_ply.py reads every file back with it) and surfnorm.to_open3d
OPEN3D_VERSION := 0.20.0
OPEN3D_STAMP := $(VENV)/.open3d-installed-$(OPEN3D_VERSION)
# The authors' d2nt package: the peer that the speed benchmark and the tests compare with
D2NT_STAMP := $(VENV)/.d2nt-installed-0.1.3

.PHONY: demo test test-fast lint docs doctest bench pictures clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): $(PY) pyproject.toml
	$(PY) -m pip install -q -e .
	touch $@

$(TEST_STAMP): $(STAMP)
	$(PY) -m pip install -q -e ".[test]"
	touch $@

# A separate step, so that a failure says that it was PyTorch that could not be installed.
$(TORCH_STAMP): $(STAMP)
	@echo "Installing PyTorch $(TORCH_VERSION) (CPU build) for the tests of surfnorm.torch"
	@$(PY) -m pip install -q "torch==$(TORCH_VERSION)" || { \
		echo "make test: could not install torch==$(TORCH_VERSION), needed by tests/test_torch.py" >&2; exit 1; }
	touch $@

# A separate step, so that a failure says that it was Open3D. On Linux its import needs the system library
# libusb-1.0-0, which a bare Debian machine lacks: installed here with apt-get where this runs as root.
$(OPEN3D_STAMP): $(STAMP)
	@echo "Installing Open3D $(OPEN3D_VERSION) for the tests of the PLY point clouds and surfnorm.to_open3d"
	@if [ "$$(uname -s)" = Linux ] && ! ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0' \
		&& [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "Installing the system library libusb-1.0-0 that Open3D needs (apt-get)"; \
		apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 \
		|| { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1; } || true; \
	fi
	@$(PY) -m pip install -q "open3d==$(OPEN3D_VERSION)" && $(PY) -c "import open3d" || { \
		echo "make test: could not install or import open3d==$(OPEN3D_VERSION), needed by tests/test_ply.py" \
		"(on Linux it needs libusb-1.0-0: apt-get install libusb-1.0-0)" >&2; exit 1; }
	touch $@

demo: $(STAMP)
	$(VENV)/bin/surfnorm demo demo-output

test: $(TEST_STAMP) $(TORCH_STAMP) $(OPEN3D_STAMP) $(D2NT_STAMP)
	@$(MAKE) --no-print-directory lint docs doctest
	$(PY) -m pytest -q

# The same environment as make test; --every-module fails the run if a module of src/surfnorm ran no code.
test-fast: $(TEST_STAMP) $(TORCH_STAMP) $(OPEN3D_STAMP) $(D2NT_STAMP)
	$(PY) -m pytest -q -m "not slow" --every-module

lint: $(TEST_STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .
	$(PY) -m mypy

# --strict: a warning (a broken link, a docstring griffe cannot parse, a page missing from nav) fails the build
docs: $(TEST_STAMP)
	$(PY) -m mkdocs build --strict --quiet --site-dir site

# The examples in the public docstrings and in the documentation's pages, run as they are written.
doctest: $(TEST_STAMP) $(TORCH_STAMP) $(OPEN3D_STAMP)
	$(PY) -m pytest -q --doctest-modules --doctest-glob='*.md' src/surfnorm docs

# d2nt 0.1.3 declares opencv-python; --no-deps keeps our opencv-python-headless, which provides the same cv2.
$(D2NT_STAMP): $(STAMP)
	$(PY) -m pip install -q --no-deps d2nt==0.1.3
	touch $@

bench: $(D2NT_STAMP)
	NUMBA_NUM_THREADS=1 $(PY) benchmarks/speed.py --out bench-output

SENSOR_SAMPLE ?=
pictures: $(STAMP)
	$(PY) benchmarks/docs_pictures.py $(if $(SENSOR_SAMPLE),--sensor $(SENSOR_SAMPLE))

clean:
	rm -rf $(VENV) demo-output bench-output site .mypy_cache .ruff_cache
	find src -name '*.nbi' -o -name '*.nbc' | xargs rm -f
	rm -f src/surfnorm/_aot_*.so src/surfnorm/_aot_index.json
