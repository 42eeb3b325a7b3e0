# Two commands on a new machine: `make demo` (main job on the built-in virtual cubicle)
# and `make test`. Each bootstraps what it needs: system OpenCL/EGL pieces, a .venv, the package.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
OUT    ?= demo_out

.PHONY: demo test test-fast bench lint setup system clean check-install

setup: system $(STAMP)

system:
	@bash tools/install_system.sh

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/rtdefocus demo -o $(OUT)

# The set-up installs PoCL and Mesa: a missing OpenCL device or EGL context fails the run
# instead of skipping the tests that need it. .ci/run is exactly this target.
test: setup
	RTDEFOCUS_REQUIRE_DEVICES=1 $(PY) -m pytest -q -ra
	@bash tools/check_plain_install.sh

# The edit loop: everything but the long end-to-end runs (marked slow), devices required.
test-fast: setup
	RTDEFOCUS_REQUIRE_DEVICES=1 $(PY) -m pytest -q -ra -m "not slow"

check-install: system
	@bash tools/check_plain_install.sh

lint: setup
	$(VENV)/bin/ruff check rtdefocus tests tools

bench: setup
	$(PY) tools/bench.py

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache build *.egg-info
