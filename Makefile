# Two commands for a fresh machine: `make demo` and `make test` (see README).
# TORCH pins the torch wheel; on a machine without a GPU and no local CPU wheel, add
#   TORCH_INDEX=--extra-index-url=https://download.pytorch.org/whl/cpu
# to avoid downloading the multi-GB CUDA build.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
TORCH ?= torch==2.13.0
TORCH_INDEX ?=
CHROMIUM ?= /usr/bin/chromium
PYTEST_ARGS ?=

.PHONY: demo test venv test-venv chromium bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(TORCH_INDEX) "$(TORCH)"
	$(PY) -m pip install -q -e .
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(PY) -m pip install -q -e ".[test]"
	touch $@

venv: $(VENV)/.installed

test-venv: $(VENV)/.installed-test

# Browser tests drive Debian's Chromium through Playwright; never download a browser at run time.
chromium:
	@if [ ! -x "$(CHROMIUM)" ]; then \
	  if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	      || echo "warning: could not install chromium; browser tests will be skipped"; \
	  else echo "warning: $(CHROMIUM) missing and apt-get unavailable; browser tests will be skipped"; fi; \
	fi

# The CPU kernels compile on a first run (~80 s on two cores): the viewer serves its page at once
# and shows the compile's progress there and in the terminal before SLAM starts.
# (`$(PY) -m app.warmup` compiles them ahead of time, e.g. when building an image.)
demo: venv
	$(VENV)/bin/splatam-viewer

test: test-venv chromium
	OMP_WAIT_POLICY=PASSIVE $(PY) -m pytest -q -rs $(PYTEST_ARGS)

bench: venv
	$(PY) benchmarks/render.py --json

clean:
	rm -rf $(VENV) .pytest_cache
