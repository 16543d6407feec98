# posecast developer entry points. Two commands matter on a fresh machine:
#   make run   - start posecast with the shipped model and a simulated player
#   make test  - lint, type-check and run the whole test suite
# Both create (or reuse) a local virtualenv in .venv and install what they need.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)

.PHONY: run test lint typecheck pytest venv clean
# The targets share one .venv: two pip installs into it at once (make -j) would race.
.NOTPARALLEL:

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

# make run needs only the serving install and the data extra (scipy: the demo's
# generated walk derives its contact labels), about 0.4 GB; make test adds the [dev]
# extra (torch for training and the parity tests, the gates, Redis; about 6 GB).
RUN_STAMP := $(VENV)/.run-installed-$(shell cat pyproject.toml client_sdk/python/pyproject.toml | cksum | cut -d' ' -f1)

$(RUN_STAMP): $(PY) pyproject.toml client_sdk/python/pyproject.toml
	$(PY) -m pip install --quiet -e ".[data]" -e client_sdk/python
	rm -f $(VENV)/.run-installed-*
	touch $@

$(STAMP): $(PY) pyproject.toml
	$(PY) -m pip install --quiet -e ".[dev]" -e "client_sdk/python[serial,hid]"
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

# The native kernels (server/native, built by setup.py as posecast._native): the
# editable install compiles them; a change to their sources rebuilds them here.
NATIVE_SRC   := setup.py $(wildcard server/native/*.c server/native/*.h)
NATIVE_STAMP := $(VENV)/.native-built

$(NATIVE_STAMP): $(RUN_STAMP) $(NATIVE_SRC)
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -c "from posecast import _native; print('posecast native kernels:', _native.isa() + ', precision', _native.precision())" \
	  || echo "posecast: the native kernels did not build; the engine serves with the onnx backend"
	touch $@

venv: $(STAMP) $(NATIVE_STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check server tests benchmarks client_sdk/python proto
	$(VENV)/bin/ruff format --check server tests benchmarks client_sdk/python proto

typecheck: $(STAMP)
	$(VENV)/bin/mypy

pytest: $(STAMP) $(NATIVE_STAMP)
	$(PY) -m pytest -q

# The TypeScript SDK (client_sdk/typescript): npm ci when the lock file changed, strict
# tsc, then the proto vectors, unit, integration (a real .venv posecast) and README tests.
TS_DIR := client_sdk/typescript
.PHONY: ts-test

$(TS_DIR)/node_modules/.installed: $(TS_DIR)/package-lock.json
	cd $(TS_DIR) && npm ci --no-audit --no-fund
	touch $@

ts-test: $(STAMP) $(NATIVE_STAMP) $(TS_DIR)/node_modules/.installed
	cd $(TS_DIR) && npm run --silent typecheck && npm test --silent

# The live viewer's one-file bundle, server/posecast/online/shell/static/viewer.js, from
# client_sdk/typescript/viewer/ and src/ (three.js included). It is generated and committed
# (.gitattributes marks it): rebuild it in the commit of any change that reaches it;
# tests/online/shell/test_http.py fails while it is stale.
.PHONY: viewer

viewer: $(TS_DIR)/node_modules/.installed
	cd $(TS_DIR) && npm run --silent build:viewer

# The C# SDK for Unity (client_sdk/csharp): Mono's mcs builds the library and its test
# runner (C# 7.x, which Unity compiles too), then the proto vectors, unit, end-to-end
# (a real .venv posecast) and README tests run; the last line reads "N passed, N failed".
# Mono is installed where possible (root + apt-get); elsewhere one SKIPPED line.
.PHONY: cs-test

cs-test: $(STAMP) $(NATIVE_STAMP)
	client_sdk/csharp/Tests~/run.sh

test: lint typecheck ts-test cs-test pytest

run: $(RUN_STAMP) $(NATIVE_STAMP)
	$(PY) -m posecast demo

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache
