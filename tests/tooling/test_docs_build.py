"""The documentation builds with Sphinx with every warning an error, as ``make docs`` builds it.

The build runs in a subprocess into a temporary folder (``docs/_build`` is left alone), with the
same options as the Makefile's ``docs`` target. Warnings include those of the docstrings rendered by
autodoc, so a docstring that breaks the reStructuredText of the API reference fails this test.
"""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

from repo_paths import ROOT

DOCS = ROOT / "docs"

#: pages every build must produce (training.md is written separately and may not exist yet)
PAGES = (
    "index",
    "getting_started",
    "concepts",
    "torchrl_integration",
    "coming_from_pyrado",
    "parity",
    "benchmarks",
    "api",
    "own_robot",
    "control_suite",
)

#: objects the API reference must document (a sample from every module it covers)
API_OBJECTS = (
    "torchtasks.spaces.Box",
    "torchtasks.rewards.QuadraticErrorReward",
    "torchtasks.rewards.CompoundReward",
    "torchtasks.tasks.Task",
    "torchtasks.tasks.FinalRewardTask",
    "torchtasks.tasks.SequentialTasks",
    "torchtasks.predefined.lifting_task",
    "torchtasks.transforms.TaskTransform",
    "torchtasks.transforms.TaskTransform.reward_fn",
    "torchtasks.envs.PendulumEnv",
    "torchtasks.envs.swing_up_task",
    "torchtasks.envs.locomotion.gymnasium_env",
    "torchtasks.envs.readings.body_lin_vel",
    "torchtasks.envs.readings.BodyLinVel",
    "torchtasks.envs.mujoco_declaration.Resets",
    "torchtasks.envs.mujoco_declaration.declare",
    "torchtasks.envs.reset_steps.UntilContactFree",
    "torchtasks.envs.models.model_path",
    "torchtasks.envs.reset_steps.UniformJoints",
    "torchtasks.envs.control_suite.control_suite_env",
    "torchtasks.envs.control_suite.check.compare_with_dm_control",
    "torchtasks.parity.check_parity",
    "torchtasks.cli.main",
)

BUILD_TIMEOUT = 600  # seconds; a build takes ~15 s on an idle 2-core machine


@pytest.mark.slow
@pytest.mark.xdist_group("docs")
def test_docs_build_without_warnings(tmp_path: Path) -> None:
    html = tmp_path / "html"
    command = [
        sys.executable,
        "-m",
        "sphinx",
        "-W",
        "--keep-going",
        "-q",
        "-b",
        "html",
        "-d",
        str(tmp_path / "doctrees"),
        str(DOCS),
        str(html),
    ]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=BUILD_TIMEOUT, check=False)
    assert result.returncode == 0, (
        f"sphinx-build failed (exit code {result.returncode}); fix the warnings below "
        f"(they are errors, as in `make docs`):\n{result.stderr[-8000:]}\n{result.stdout[-2000:]}"
    )
    for page in PAGES:
        assert (html / f"{page}.html").is_file(), f"{page}.html was not built"
    api = (html / "api.html").read_text(encoding="utf-8")
    documented = set(re.findall(r'<dt class="sig sig-object py" id="([^"]+)"', api))
    missing = [name for name in API_OBJECTS if name not in documented]
    assert not missing, f"the API reference does not document {missing}"
    # the table of reading kinds (docs/conf.py, from READING_KINDS): a row per kind with its shape
    table = api.split("value, shape and frame", 1)[1].split("</table>", 1)[0]
    rows = re.findall(r"<tr[^>]*>(.*?)</tr>", table, flags=re.DOTALL)
    kinds = [re.sub(r"<[^>]+>", "", row).split()[0] for row in rows]
    if importlib.util.find_spec("mujoco") is not None:
        from torchtasks.envs.readings import READING_KINDS

        assert kinds == [f"{kind}()" for kind in READING_KINDS], kinds
        assert all("shape" in row for row in rows), "a reading kind's row does not state its shape"
        # the tables of the Control Suite's tasks (docs/conf.py, from the presets): a row per task in each
        from torchtasks.envs.control_suite import CONTROL_SUITE_TASKS

        page = (html / "control_suite.html").read_text(encoding="utf-8")
        tables = re.findall(r"<thead>(.*?)</thead>\s*<tbody>(.*?)</tbody>", page, flags=re.DOTALL)
        for header in ("control step", "reset steps"):
            body = next(body for head, body in tables if header in head)
            rows = re.findall(r"<tr[^>]*>(.*?)</tr>", body, flags=re.DOTALL)
            names = [re.sub(r"<[^>]+>", " ", row).split()[0] for row in rows]
            assert names == list(CONTROL_SUITE_TASKS), (header, names)
