# skelfem: two commands do everything on a fresh Debian 12 / Ubuntu machine.
#   make demo   install what is missing, simulate geometry/finger.toml into results/finger
#   make test   install what is missing, run the test suite
#   make lint   ruff and mypy (the rules: pyproject.toml; CI runs it first)
# and one more builds the documentation:
#   make docs   install what is missing, build docs/ into docs/_build/html (runs the examples)
SHELL := /bin/bash
.DEFAULT_GOAL := demo

# DOLFINx 0.5.2 and its stack come from Debian; everything else lives in a
# venv that sees the system site-packages (numpy/scipy pinned to Debian's).
# The editor's web stack (Starlette, uvicorn, websockets, tomlkit) and what its
# browser tests drive (Chromium, chromedriver, Selenium) are Debian's too:
# nothing downloads a browser at run time. The documentation's tools (Sphinx,
# MyST, the furo theme, sphinx-gallery) are Debian's too, and so is the slicer
# the fabrication study checks the printed parts with (prusa-slicer).
APT_PACKAGES := python3-dolfinx python3-gmsh python3-meshio python3-venv python3-pil \
	python3-scipy python3-matplotlib python3-pytest python3-setuptools python3-h5py \
	libopenblas0-pthread openmpi-bin libegl1 libegl-mesa0 libgl1-mesa-dri admesh \
	python3-starlette python3-uvicorn python3-websockets python3-tomlkit \
	python3-selenium chromium chromium-driver \
	python3-sphinx python3-myst-parser furo python3-sphinx-gallery python3-pytest-xdist prusa-slicer
SYSPY := /usr/bin/python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.skelfem-installed
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
export OMPI_MCA_mpi_yield_when_idle := 1
export OPENBLAS_NUM_THREADS := 1
export OMP_NUM_THREADS := 1
export MPLBACKEND := Agg

.PHONY: demo test test-fast lint docs setup system clean

demo: setup
	$(VENV)/bin/skelfem simulate geometry/finger.toml --out results/finger

# The whole suite: two workers for everything but the mpirun tests, then those two at a time (four
# ranks on two cores: Open MPI's ranks yield when idle, and much of each test is starting Python on
# both ranks: 186 s one at a time, 144 s two at a time); the slowest tests are listed. test-fast skips
# the slow tier (the edit loop).
test: setup
	$(PY) -m pytest -q -n 2 -m "not mpi" --durations=60
	$(PY) -m pytest -q -n 2 -m mpi --durations=20

test-fast: setup
	$(PY) -m pytest -q -n 2 -m "not slow and not mpi" --durations=10

# Lint and types, pinned in pyproject.toml's lint extra: ruff over the repository, mypy over the public
# API and the core layers (both configured in pyproject.toml).
lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

# The documentation: MyST pages, the gallery of examples (each one runs), the API
# from the docstrings and tables read from studies/output/; warnings are errors.
docs: system setup
	$(PY) -m sphinx -W --keep-going -b html docs docs/_build/html
	@echo "documentation in docs/_build/html/index.html"

setup: $(STAMP)

# System packages: installed only when one is missing.
system:
	@missing=$$(for p in $(APT_PACKAGES); do \
		dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || echo $$p; done); \
	if [ -n "$$missing" ]; then \
		echo "installing system packages:" $$missing; \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(STAMP): pyproject.toml | system
	@[ -x $(PY) ] || $(SYSPY) -m venv --system-site-packages $(VENV)
	@$(SYSPY) -c "import numpy, scipy, matplotlib; \
		print(f'numpy=={numpy.__version__}\nscipy=={scipy.__version__}\nmatplotlib=={matplotlib.__version__}')" \
		> $(VENV)/constraints.txt
	$(PY) -m pip install -q --no-build-isolation -c $(VENV)/constraints.txt -e ".[test,study,lint]"
	@$(PY) -c "import dolfinx, skelfem; print('skelfem ready: dolfinx', dolfinx.__version__)"
	@touch $@

clean:
	rm -rf $(VENV) results .pytest_cache docs/_build docs/auto_examples
