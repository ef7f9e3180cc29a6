# Two entry points for a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup demo test check-base-install lint docs bench clean

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints.txt torch==2.13.0
	$(BIN)/pip install --quiet -c constraints.txt -e ".[dev,mujoco,ray]"
	# test-only reference: dm_control's reward utilities (numpy only; the rest of dm_control needs an older mujoco)
	$(BIN)/pip install --quiet --no-deps dm-control==1.0.50
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/torchtasks demo --output runs/demo

test: $(STAMP)
	$(BIN)/ruff check src tests examples benchmarks
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

# the base install (no extras) in a fresh temporary venv: core import, `torchtasks list`, `torchtasks demo --quick`
check-base-install:
	bash .ci/check_base_install.sh $(PY)

docs: $(STAMP)
	$(BIN)/sphinx-build -W --keep-going -b html docs docs/_build/html

lint: $(STAMP)
	$(BIN)/ruff check src tests examples benchmarks
	$(BIN)/ruff format --check src tests examples benchmarks

clean:
	rm -rf $(VENV) docs/_build
