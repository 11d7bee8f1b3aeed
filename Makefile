# Two commands for a fresh machine: `make demo` (main job on embedded defaults)
# and `make test` (test suite). Both install into .venv first; the install is
# skipped in seconds when .venv is current (stamp file newer than pyproject.toml).

VENV    := .venv
PY      := $(VENV)/bin/python
PIP     := $(PY) -m pip --disable-pip-version-check -q
STAMP   := $(VENV)/.m3gd-installed
PYTEST  := $(PY) -m pytest -p no:dash
export MPLBACKEND := Agg

.PHONY: demo test test-all lint docs install clean-venv mutate

install: $(STAMP)

$(STAMP): pyproject.toml bench/pyproject.toml Makefile
	@echo ">> system library libusb-1.0-0 (open3d needs it)"
	@ldconfig -p | grep -q 'libusb-1.0.so.0' || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 || \
	  { $$SUDO apt-get update -q >/dev/null && $$SUDO apt-get install -y -q libusb-1.0-0 >/dev/null; }; }
	@echo ">> Debian's chromium (the report tests drive it headless)"
	@command -v chromium >/dev/null 2>&1 || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get install -y -q --no-install-recommends chromium >/dev/null 2>&1 || \
	  { $$SUDO apt-get update -q >/dev/null && \
	    $$SUDO apt-get install -y -q --no-install-recommends chromium >/dev/null; }; }
	@echo ">> virtual environment $(VENV)"
	@[ -x $(PY) ] || python3 -m venv $(VENV)
	@echo ">> torch 2.13.0 CPU build first (a plain torch would pull a CUDA build)"
	@$(PIP) install torch==2.13.0
	@echo ">> m3gd and its dependencies"
	@$(PIP) install -e '.[dev,da3]'
	@echo ">> the benchmarks beside it (m3gd-bench: m3gd bench ... through its entry point)"
	@$(PIP) install --no-deps -e ./bench
	@echo ">> depth-anything-3 without its dependencies (SPEC.md section 7)"
	@$(PIP) install --no-deps depth-anything-3==0.1.1
	@if $(PIP) show opencv-python >/dev/null 2>&1; then \
	  echo "opencv-python was pulled in beside opencv-contrib-python-headless" >&2; exit 1; fi
	@touch $(STAMP)

# The main job, then the HTML report (written even when a stage failed: it shows which);
# `make demo` exits with the job's status.
demo: $(STAMP)
	@$(VENV)/bin/m3gd demo; status=$$?; \
	  $(VENV)/bin/m3gd report --no-plots || status=1; exit $$status

# The model tests once more on torch's generic CPU kernels: a numeric bound read off one
# CPU's run must hold on any (docs/testing.md). The loader tests read files, not numerics.
MODEL_TEST_SEED ?= 1336312577
MODEL_TESTS_GENERIC := ATEN_CPU_CAPABILITY=default $(PYTEST) -m "not slow" -q tests/model \
	--ignore=tests/model/test_dataset.py --ignore=tests/model/test_dataset_s3.py \
	-p randomly --randomly-seed=$(MODEL_TEST_SEED)

# The suite runs in a shuffled order (pytest-randomly). CI uses one verified order; any other:
# `make test TEST_SEED=$$RANDOM` (the seed is printed at the end of every run).
TEST_SEED ?= 2102816138

test: $(STAMP) lint docs
	$(PYTEST) -m "not slow" -p randomly --randomly-seed=$(TEST_SEED) --durations=15
	$(MODEL_TESTS_GENERIC)

# Mutation testing of packets/ and pipeline/select/ ([tool.mutmut] in pyproject.toml; results
# and survivors in docs/testing.md). About an hour on one core, so not part of `test`; one module:
# `make mutate MUTANTS='packets.time_offset.*'`. Mutants and results stay in mutants/.
# The `mutation` hypothesis profile (tests/conftest.py): at most 10 derandomized examples per
# property test, no shrinking.
MUTANTS ?=
mutate: $(STAMP)
	M3GD_HYPOTHESIS_PROFILE=mutation $(VENV)/bin/mutmut run --max-children 1 $(MUTANTS)
	$(VENV)/bin/mutmut results

test-all: $(STAMP) lint docs
	$(PYTEST) --durations=25

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy --strict schemas packets store pipeline model cli dags
	$(VENV)/bin/lint-imports --no-cache

# The docs site (MkDocs + Material) into site/; the reference pages are generated from the
# code by docs_gen/hooks.py. --strict: a broken link or a missing page fails the build.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 PYTHONPATH=$(CURDIR) $(VENV)/bin/mkdocs build --strict -q

clean-venv:
	rm -rf $(VENV)
