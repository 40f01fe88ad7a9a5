# Two commands do all the set-up: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

DEBIAN_PACKAGES := libblas3 liblapack3 chromium chromium-driver

.PHONY: run test bench clean debian

# openseespy (the OpenSees tests and examples) needs Debian's BLAS and LAPACK; the monitor's browser
# tests drive Debian's chromium through its chromedriver.
debian:
	@dpkg -s $(DEBIAN_PACKAGES) > /dev/null 2>&1 || { \
	  echo "installing Debian packages: $(DEBIAN_PACKAGES)"; \
	  (apt-get update -qq && apt-get install -y -qq $(DEBIAN_PACKAGES)) > /dev/null 2>&1 || \
	  echo "could not install $(DEBIAN_PACKAGES) (not root?): the OpenSees and browser tests will be skipped"; }

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	@echo "installing hsio and its test dependencies into $(VENV) (log: $(VENV)/install.log)"
	@$(BIN)/python -m pip install --upgrade pip > $(VENV)/install.log 2>&1 || { cat $(VENV)/install.log; exit 1; }
	@$(BIN)/python -m pip install -e ".[test]" >> $(VENV)/install.log 2>&1 || { cat $(VENV)/install.log; exit 1; }
	@touch $(STAMP)

run: $(STAMP)
	$(BIN)/hsio run

# The suite runs on every core up to four (pytest-xdist): most tests wait on emulators, sockets
# and subprocesses. HSIO_TEST_WORKERS=0 runs it in one process.
HSIO_TEST_WORKERS ?= auto
test: debian $(STAMP)
	$(BIN)/python -m pytest -q -n $(HSIO_TEST_WORKERS) --maxprocesses 4

bench: $(STAMP)
	for b in bench/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) runs build *.egg-info
