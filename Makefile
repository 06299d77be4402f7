# Developer tasks for the ovrad Blender extension. `make test` and `make demo` work from a fresh
# clone: they create .venv first. Targets: venv wheels build test test-versions demo scene lint
# format clean.

SHELL := /bin/bash
.DEFAULT_GOAL := test

# bpy 5.0.x exists for Python 3.11 only: prefer an explicit python3.11.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
# Re-installs only when the requirements change (or the venv is new).
VENV_STAMP := $(VENV)/.stamp-requirements

# Python 3.13 for bpy 5.3 (pyenv on the project's machines; a plain python3.13 works too).
PYTHON313 ?= env PYENV_VERSION=3.13.0 python3.13

# Cross-version tests: each supported Blender as the bpy module in its own venv (the bpy wheel
# is ~400 MB: downloaded once, kept there; re-installed only when its requirements change).
BLENDER_VERSIONS := 42 45 53
VENV_PYTHON_42 = $(PYTHON)
VENV_PYTHON_45 = $(PYTHON)
VENV_PYTHON_53 = $(PYTHON313)
VERSION_STAMPS := $(foreach v,$(BLENDER_VERSIONS),.venv-bpy$(v)/.stamp-requirements)
# The tests marked `versions` (pyproject.toml) live here; --confcutdir keeps pytest from importing
# the repository root's __init__.py (the extension, which needs its wheels).
VERSION_TESTS := tests/test_extension_package.py tests/blender

BLENDER := scripts/blender
LINUX_ZIP_CMD := $(PY) scripts/build_extension.py --split-platforms --platform linux-x64 -q --no-fetch
# `make demo` keeps its own Blender user folder (installed extension, preferences) under out/.
DEMO_USER := $(CURDIR)/out/blender-user
DEMO_ENV := env -u BLENDER_USER_CONFIG -u BLENDER_USER_SCRIPTS -u BLENDER_USER_EXTENSIONS \
	-u BLENDER_USER_DATAFILES BLENDER_USER_RESOURCES=$(DEMO_USER)

.PHONY: venv wheels build test test-versions demo scene lint format clean

venv: $(VENV_STAMP)

$(VENV_STAMP): requirements-dev.txt
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || \
		{ echo "error: $(PYTHON) is not Python 3.11 (bpy 5.0 needs it); set PYTHON=..." >&2; exit 1; }
	@# A venv left half-made (no pip) by an earlier failure is made again from scratch.
	@if ! $(PY) -m pip --version >/dev/null 2>&1; then \
		echo "creating $(VENV) with $(PYTHON)"; \
		$(PYTHON) -m venv --clear $(VENV); \
	fi
	$(PY) -m pip install --disable-pip-version-check -q -r requirements-dev.txt
	@touch $@

# Wheels the extension ships (blender_manifest.toml); already-present files are skipped.
wheels: venv
	$(PY) scripts/fetch_wheels.py

# One zip per platform in dist/; rebuilt only when a packed file is newer than the zip.
build: venv
	$(PY) scripts/build_extension.py --split-platforms

test: venv build
	$(PY) -m pytest -q tests

# The built linux zip installed by each Blender's own installer into bpy 4.2 LTS, 4.5 LTS and 5.3
# (Python 3.13), then the tests marked `versions`: one pytest process per Blender.
test-versions: venv build $(VERSION_STAMPS)
	@zip="$$($(LINUX_ZIP_CMD))"; status=0; ref="$(CURDIR)/build/versions_bake.npz"; rm -f "$$ref"; \
	echo "== the development Blender's bakes (.venv), which the others must give again"; \
	OVRAD_WRITE_VERSIONS_REFERENCE="$$ref" $(PY) -m pytest --confcutdir tests -q -m versions \
		tests/blender/test_versions_agree.py || status=1; \
	for v in $(BLENDER_VERSIONS); do \
		start=$$(date +%s); \
		echo "== Blender $$(.venv-bpy$$v/bin/python -c 'import importlib.metadata as m; print(m.version("bpy"))') (.venv-bpy$$v)"; \
		OVRAD_EXTENSION_ZIP="$$zip" OVRAD_VERSIONS_REFERENCE="$$ref" .venv-bpy$$v/bin/python -m pytest --confcutdir tests -q -m versions \
			$(VERSION_TESTS) || status=1; \
		echo "== .venv-bpy$$v: $$(( $$(date +%s) - start )) s"; \
	done; exit $$status

.venv-bpy%/.stamp-requirements: requirements-bpy%.txt
	@if ! $(@D)/bin/python -m pip --version >/dev/null 2>&1; then \
		echo "creating $(@D) with $(VENV_PYTHON_$*)"; \
		$(VENV_PYTHON_$*) -m venv --clear $(@D); \
	fi
	$(@D)/bin/python -m pip install --disable-pip-version-check -q -r $<
	@touch $@

demo: venv build
	@mkdir -p out
	$(DEMO_ENV) $(BLENDER) -b -c extension install-file -r user_default -e "$$($(LINUX_ZIP_CMD))"
	$(DEMO_ENV) $(BLENDER) -b scenes/cornell.blend --python-exit-code 1 -P scripts/ovrad_demo.py -- \
		--output out/cornell_ovrad.blend --picture out/cornell_ovrad.png

# Rebuild the bundled Cornell box (deterministic; commit the result).
scene: venv
	$(BLENDER) -b --python-exit-code 1 --python scripts/make_cornell.py -- --output scenes/cornell.blend

lint: venv
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: venv
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

clean:
	rm -rf dist out build .pytest_cache .ruff_cache
	find . -path './.venv*' -prune -o -name __pycache__ -type d -print0 | xargs -0 rm -rf
	@echo "kept $(VENV)/, .venv-bpy*/ and wheels/ (downloads): rm -rf them by hand to start over"
