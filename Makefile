# fusegraph: `make demo` and `make test` build everything they need from nothing.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: venv install sysdeps browser demo test docs lint bench clean

# Python writes the bytecode of what it imports (__pycache__, gitignored) even where the shell says not to: with
# PYTHONDONTWRITEBYTECODE set and pip's --no-compile below, every process compiled every module it imported from
# source again (5.0 s to import the CLI, gtsam and scikit-learn; 2.4 s from the cache), in each test worker, each
# CLI test's subprocess and each process-pool or Dask worker
unexport PYTHONDONTWRITEBYTECODE

# Debian packages open3d's headless renderer needs (open3d-cpu links libusb; offscreen rendering
# runs on Mesa's Vulkan llvmpipe). Installed when we are root and they are missing; otherwise we say so
# and `fusegraph view` falls back to a matplotlib render.
SYSDEPS := libusb-1.0-0 libvulkan1 mesa-vulkan-drivers

sysdeps:
	@if dpkg -s $(SYSDEPS) >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(SYSDEPS) >/dev/null; \
	else echo "note: install $(SYSDEPS) (Debian) for open3d's offscreen renderer; fusegraph view falls back to matplotlib"; fi

venv: $(STAMP)

# one environment for tests, reports and benches; re-installed when pyproject.toml changes
$(STAMP): pyproject.toml
	$(MAKE) --no-print-directory sysdeps
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# --no-compile: byte-compiling every installed module (plotly's and open3d's thousands) took ~20 s of a fresh
	# environment's ~45; Python compiles the modules a run imports when it first imports them
	$(BIN)/python -m pip install --quiet --no-compile -e ".[dev,docs]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	mkdir -p out
	$(BIN)/fusegraph report head --seeds 0-9 --plot out/head_tracking.png
	@echo "figure: out/head_tracking.png (reference, tracker, Method II and iSAM2 per axis)"

# the tests on every core (pytest-xdist: 2 cores take about half the time of one), with mypy beside them: on a fresh
# clone it has no cache and took 19 s after the tests; its report is printed when they end, and either failing fails
test: $(STAMP)
	$(BIN)/ruff check fusegraph tests
	@$(BIN)/mypy fusegraph > .mypy.out 2>&1 & types=$$!; \
	$(BIN)/python -m pytest -q -n auto; tests=$$?; \
	wait $$types; typed=$$?; echo "mypy fusegraph:"; cat .mypy.out; rm -f .mypy.out; \
	test $$tests -eq 0 && test $$typed -eq 0

# the documentation site (mkdocs-material + mkdocstrings) into site/, warnings as errors: a broken link or a stale
# reference fails; the CLI reference, the settings tables, the dataset pages and the frames figures are generated
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet
	@echo "site/index.html"

# Debian's chromium for the test that opens `report --html` in a headless browser (installed when we are root)
browser: $(STAMP)
	@if command -v chromium >/dev/null; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } \
	  || echo "note: chromium could not be installed: the browser test skips, saying so"; \
	else echo "note: install chromium (Debian) for the headless-browser test of report --html"; fi
	$(BIN)/python -m pytest -q tests/test_html_report.py

lint: $(STAMP)
	$(BIN)/ruff check fusegraph tests
	$(BIN)/mypy fusegraph

bench: $(STAMP)
	$(BIN)/fusegraph report head --seeds 0-9 --profile ideal
	$(BIN)/fusegraph report head --seeds 0-9 --profile realistic
	$(BIN)/fusegraph bench head --duration 600 --repeat 3

clean:
	rm -rf $(VENV) out site docs/figures .pytest_cache .mypy_cache .ruff_cache *.egg-info
