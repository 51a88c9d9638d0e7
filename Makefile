# Two entry points do everything on a fresh Debian machine: `make demo` and `make test`.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
SCENARIO ?= highway-omni-near
# processes the tests run in; a test file stays in one (its module fixtures are shared)
TEST_WORKERS ?= 2
export PYOPENGL_PLATFORM := osmesa

.PHONY: setup demo test test-deps bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	@dpkg -s libosmesa6 >/dev/null 2>&1 || { apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y libosmesa6; }
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev,ray]"
	# pyrender 0.1.45 pins PyOpenGL==3.1.0, whose OSMesa binding lacks
	# OSMesaCreateContextAttribs: install a working PyOpenGL over it (docs/INSTALL.md).
	$(PY) -m pip install --quiet "PyOpenGL==3.1.10"
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/omnibench run $(SCENARIO) --out renders/demo

# headless Chromium opens the HTML reports in the tests
test-deps:
	@command -v chromium >/dev/null 2>&1 || { apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y chromium; }

test: $(STAMP) test-deps
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

bench: $(STAMP)
	$(VENV)/bin/omnibench bench render

clean:
	rm -rf $(VENV) renders/demo
