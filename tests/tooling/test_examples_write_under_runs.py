"""Every example writes under ``runs/<example name>/`` of the current directory and nowhere else there (issue 23).

Running every example's ``--quick`` once more would cost minutes, so the check rides on the runs the
example tests make anyway: ``run_example`` in ``test_examples.py`` and ``test_examples_training.py``
runs the script through :func:`run_quick` (``tests/example_runs.py``), from a fresh empty directory,
and :func:`run_quick` fails if anything but ``runs/`` appears there, or anything in ``runs/`` but
``runs/<example name>/``.
MuJoCo's ``MUJOCO_LOG.TXT`` counts: it is a file left in the user's directory like any other.

This module checks that every runnable script in ``examples/`` (not the ``_``-prefixed helpers) is
run that way, without ``--output``, by at least one test.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from example_runs import EXAMPLES

TESTS = Path(__file__).resolve().parent  # this folder, beside the example tests below
EXAMPLE_TESTS = ("test_examples.py", "test_examples_training.py")


def runnable_examples() -> list[str]:
    """The file names of the example scripts (``examples/*.py`` without the ``_``-prefixed helpers)."""
    return sorted(path.name for path in EXAMPLES.glob("*.py") if not path.name.startswith("_"))


def _scripts_run_without_output(test_module: Path) -> set[str]:
    """The scripts that ``test_module`` passes to ``run_example`` in a call without ``--output``."""
    scripts = set()
    for node in ast.walk(ast.parse(test_module.read_text())):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "run_example"):
            continue
        constants = [arg.value for arg in node.args if isinstance(arg, ast.Constant)]
        if node.args and isinstance(node.args[0], ast.Constant) and "--output" not in constants:
            scripts.add(node.args[0].value)
    return scripts


def test_the_examples_are_found() -> None:
    assert {"quickstart.py", "train_swingup_ppo.py", "differentiable_shaping.py"} <= set(runnable_examples())


@pytest.mark.parametrize("script", runnable_examples())
def test_every_example_is_run_from_an_empty_directory(script: str) -> None:
    covered = set().union(*(_scripts_run_without_output(TESTS / name) for name in EXAMPLE_TESTS))
    assert script in covered, (
        f"no test in {', '.join(EXAMPLE_TESTS)} runs examples/{script} with run_example(...) and without "
        "--output: add one, so that its default outputs are checked to stay under runs/"
    )
