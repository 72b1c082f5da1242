# Two commands for a newcomer on a fresh machine:
#   make demo   set up .venv and run every estimator on the sample frames shipped in the package
#   make test   set up .venv (with the test extras and the CPU build of PyTorch) and run all tests
#   make bench  speed of the D2NT family next to the authors' d2nt package -> bench-output/speed.{md,json}
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
TEST_STAMP := $(VENV)/.test-installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)
BENCH_STAMP := $(VENV)/.bench-installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)

.PHONY: demo test bench clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): $(PY) pyproject.toml
	$(PY) -m pip install -q -e .
	touch $@

$(TEST_STAMP): $(STAMP)
	$(PY) -m pip install -q -e ".[test]"
	touch $@

demo: $(STAMP)
	$(VENV)/bin/surfnorm demo demo-output

test: $(TEST_STAMP)
	$(PY) -m pytest -q

# d2nt 0.1.3 declares opencv-python; --no-deps keeps our opencv-python-headless, which provides the same cv2.
$(BENCH_STAMP): $(STAMP)
	$(PY) -m pip install -q --no-deps d2nt==0.1.3
	touch $@

bench: $(BENCH_STAMP)
	NUMBA_NUM_THREADS=1 $(PY) benchmarks/speed.py --out bench-output

clean:
	rm -rf $(VENV) demo-output bench-output
	find src -name '*.nbi' -o -name '*.nbc' | xargs rm -f
