# Two entry points for a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
BENCH_VENV := .venv-bench
BENCH_BIN := $(BENCH_VENV)/bin
BENCH_STAMP := $(BENCH_VENV)/.installed
DMC_VENV := .venv-dmc
DMC_STAMP := $(DMC_VENV)/.installed
DMC_REQUIREMENTS := .ci/dm_control_reference.txt
BENCH_DMC_VENV := .venv-bench-dmc
BENCH_DMC_BIN := $(BENCH_DMC_VENV)/bin
BENCH_DMC_STAMP := $(BENCH_DMC_VENV)/.installed

.PHONY: setup demo test test-quick check-base-install lint docs bench bench-venv bench-dmc-venv reference-venv clean

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints.txt torch==2.13.0
	$(BIN)/pip install --quiet -c constraints.txt -e ".[dev,mujoco,ray]"
	# test-only reference: MO-Gymnasium's MuJoCo v5 envs, which the multi-objective presets reproduce bit for bit
	# (tests/envs/test_multi_objective.py, `torchtasks check mo-...`), with its requirements pygame and scipy
	# pinned. Not a dependency of torchtasks (not in pyproject.toml): the package never imports it.
	$(BIN)/pip install --quiet -c constraints.txt mo-gymnasium pygame scipy
	# test-only reference: dm_control's reward utilities (numpy only; the rest of dm_control needs an older mujoco),
	# installed without its requirements and last: an install after it would check dm-control's unmet requirements
	# and print pip's dependency-conflict report ("dm-control 1.0.50 requires absl-py ..."), which reads as a
	# failed set-up; an install with --no-deps checks nothing.
	$(BIN)/pip install --quiet --no-deps dm-control==1.0.50
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/torchtasks demo --output runs/demo

# The dm_control reference venv is built when it can be (~35 s, once); if it cannot (no network), its build says so in
# one line and the suite still runs, the dm_control reference tests skipping with the reason.
test: DMC_BUILD_ERRORS := -
test: $(STAMP) $(DMC_STAMP)
	$(BIN)/ruff check src tests examples benchmarks
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup

# A set-up check, not the suite CI runs: the tests marked `quick` (pyproject) import torchtasks, step a task, step a
# MuJoCo preset, run a Collector and a README snippet, print the CLI's help and replay Pyrado golden rollouts.
# 33.5 s on a shared 2-core machine under load ~3 (median of 3 runs: 27.7, 33.5, 34.0 s; start-up and collection ~14 s).
test-quick: $(STAMP)
	$(BIN)/python -m pytest -q -m quick tests

# the base install (no extras) in a fresh temporary venv: core import, `torchtasks list`, `torchtasks demo --quick`
check-base-install:
	bash .ci/check_base_install.sh $(PY)

docs: $(STAMP)
	$(BIN)/sphinx-build -W --keep-going -b html docs docs/_build/html

lint: $(STAMP)
	$(BIN)/ruff check src tests examples benchmarks
	$(BIN)/ruff format --check src tests examples benchmarks

# A separate venv for the peer columns of benchmarks/batched_mujoco.py: envpool (its raw step and, through
# TorchRL's MultiThreadedEnv, which also needs gym 0.26 and treevalue). None of these is a dependency of
# torchtasks, and gym beside gymnasium could change TorchRL's gym backend in the tests, so they stay out of .venv.
$(BENCH_STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(BENCH_VENV)
	$(BENCH_BIN)/pip install --quiet --upgrade pip
	$(BENCH_BIN)/pip install --quiet -c constraints.txt torch==2.13.0
	$(BENCH_BIN)/pip install --quiet -c constraints.txt -e ".[mujoco]"
	$(BENCH_BIN)/pip install --quiet -c constraints.txt envpool==1.2.5 gym==0.26.2 treevalue==1.5.0
	touch $(BENCH_STAMP)

bench-venv: $(BENCH_STAMP)

# A separate venv for the peer columns of benchmarks/control_suite.py: TorchRL's DMControlEnv needs dm_control, and
# dm-control 1.0.50 does not import on MuJoCo 4, so the project's torch, torchrl and tensordict go into a venv with
# the dm_control reference's mujoco 3.17.0 and dm-control (its requirements file; constraints.txt pins mujoco 4, so
# it is not applied there). No torchtasks: the benchmark runs benchmarks/control_suite_peer.py in it. Not built by
# `make test` or `make demo`.
$(BENCH_DMC_STAMP): constraints.txt $(DMC_REQUIREMENTS)
	$(PY) -m venv $(BENCH_DMC_VENV)
	$(BENCH_DMC_BIN)/pip install --quiet --upgrade pip
	$(BENCH_DMC_BIN)/pip install --quiet -c constraints.txt torch==2.13.0 torchrl==0.14.1 tensordict==0.14.3
	$(BENCH_DMC_BIN)/pip install --quiet -r $(DMC_REQUIREMENTS)
	MUJOCO_GL=disable $(BENCH_DMC_BIN)/python -c "import dm_control.suite, torchrl.envs.libs.dm_control"
	touch $(BENCH_DMC_STAMP)

bench-dmc-venv: $(BENCH_DMC_STAMP)

# The dm_control reference: dm-control 1.0.50 on MuJoCo 3.17.0 (it does not import on MuJoCo 4), in a venv of its own
# that the tests talk to through a worker process (torchtasks.envs.control_suite.reference). Not a dependency of
# torchtasks. `make test` builds it as a best effort (DMC_BUILD_ERRORS := - there: a failed build does not stop it).
$(DMC_STAMP): $(DMC_REQUIREMENTS) .ci/build_reference_venv.sh
	$(DMC_BUILD_ERRORS)bash .ci/build_reference_venv.sh $(PY) $(DMC_VENV) $(DMC_REQUIREMENTS)

reference-venv: $(DMC_STAMP)

clean:
	rm -rf $(VENV) $(BENCH_VENV) $(BENCH_DMC_VENV) $(DMC_VENV) docs/_build
