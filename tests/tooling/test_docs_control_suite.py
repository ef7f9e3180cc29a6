"""The tables of docs/control_suite.md say what the presets do and what was measured.

- The task tables are generated from the presets at every docs build (``docs/_scripts/control_suite_tables.py``,
  filled in by ``docs/conf.py``): on a few tasks, the generator reads dm_control's control step, observation
  entries, reward and resets (the expected values written from dm_control's suite sources, dm-control 1.0.50).
- The measured tables (``docs/_scripts/control_suite_exactness.py``) are the script's output for every task: the
  committed Markdown is what the script renders from the committed JSON, which covers every task and stays within
  ``torchtasks check``'s tolerance; the page's cheetah numbers are those of ``docs/_scripts/cheetah_settling.py``.
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from types import ModuleType

import pytest

from repo_paths import ROOT

pytest.importorskip("mujoco")

from torchtasks.envs.control_suite import CONTROL_SUITE_TASKS
from torchtasks.envs.control_suite.check import CHECK_TOLERANCE

SCRIPTS = ROOT / "docs" / "_scripts"
GENERATED = ROOT / "docs" / "_generated"
PAGE = ROOT / "docs" / "control_suite.md"


def _script(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # where its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


tables = _script("control_suite_tables")

#: from dm_control's suite sources: (timestep, substeps, {observation entry: size}), dm_control's order
DM_CONTROL = {
    "cartpole-swingup": (0.01, 1, {"position": 3, "velocity": 2}),
    "walker-walk": (0.0025, 10, {"orientations": 14, "height": 1, "velocity": 9}),
    "manipulator-bring_ball": (
        0.001,
        10,
        {"arm_pos": 16, "arm_vel": 8, "touch": 5, "hand_pos": 4, "object_pos": 4, "object_vel": 3, "target_pos": 4},
    ),
    "swimmer-swimmer15": (0.002, 15, {"joints": 14, "to_target": 2, "body_velocities": 45}),
    "quadruped-run": (
        0.005,
        4,
        {"egocentric_state": 44, "torso_velocity": 3, "torso_upright": 1, "imu": 6, "force_torque": 24},
    ),
}


@pytest.fixture(scope="module")
def facts() -> dict[str, object]:
    return {name: tables.task_facts(name) for name in DM_CONTROL}


def test_the_generated_rows_state_dm_controls_step_and_observation(facts) -> None:
    for name, (timestep, substeps, observation) in DM_CONTROL.items():
        fact = facts[name]
        assert (fact.timestep, fact.substeps) == (timestep, substeps), name
        assert list(fact.observation.items()) == list(observation.items()), name
        assert fact.flat_size == sum(observation.values()), name
    table = tables.observation_table(list(facts.values()))
    assert "| walker-walk | 0.0025 s × 10 = 0.025 s | `orientations` 14, `height` 1, `velocity` 9 | 24 |" in table
    assert len(table.splitlines()) == 2 + len(DM_CONTROL)


def test_the_generated_rows_state_dm_controls_reward_and_resets(facts) -> None:
    # walker.py: stand = (3 standing + upright) / 4, upright = (1 + zz) / 2, move = (5 tol(speed) + 1) / 6
    assert facts["walker-walk"].reward == (
        "stand · move; stand = 0.75·standing + 0.25·upright; "
        "standing = tol(torso_height, [1.2, ∞), 0.6, gaussian, 0.1); upright = tol(torso_zz, [1, ∞), 2, linear, 0); "
        "move = 5/6·tol(speed, [1, ∞), 0.5, linear, 0.5) + 1/6"
    )
    # quadruped.py: upright * move, move = tol(velocimeter x, (5, inf), margin 5, value_at_margin 0.5, linear)
    assert facts["quadruped-run"].reward == (
        "upright · move; upright = tol(torso_zz, [1, ∞), 2, linear, 0); move = tol(speed, [5, ∞), 5, linear, 0.5)"
    )
    # cartpole.py, swing_up: slider ~ 0.01 randn, hinge ~ pi + 0.01 randn, qvel ~ 0.01 randn
    assert facts["cartpole-swingup"].resets == [
        'qvel_noise=Noise("normal", 0.01)',
        "NormalJoints({slider: (0, 0.01), hinge_1: (π, 0.01)})",
    ]
    # quadruped.py: a uniform random orientation, then the lowest contact-free height in 1 cm steps
    assert facts["quadruped-run"].resets == ['RandomOrientation("root")', 'RaiseUntilContactFree("root")']
    table = tables.reward_table(list(facts.values()))
    assert len(table.splitlines()) == 2 + len(DM_CONTROL)
    assert all(row.count(" | ") == 3 for row in table.splitlines()), "a cell holds an unescaped |"


def test_constants_are_written_as_a_reader_would() -> None:
    cases = {math.pi: "π", -math.pi: "-π", 2 * math.pi: "2π", math.inf: "∞", -math.inf: "-∞", 5 / 6: "5/6"}
    cases |= {1 / 6: "1/6", 0.75: "0.75", 0.6: "0.6", 200.0: "200", math.cos(math.radians(8)): "0.990268"}
    assert {value: tables.number(value) for value in cases} == cases


def test_the_page_holds_the_markers_and_the_measured_tables() -> None:
    page = PAGE.read_text(encoding="utf-8")
    for marker in (tables.OBSERVATION_MARKER, tables.REWARD_MARKER):
        assert page.count(marker) == 1, marker
    for name in ("control_suite_exactness_table.md", "control_suite_drift_table.md"):
        assert f"```{{include}} _generated/{name}\n```" in page
        assert (GENERATED / name).is_file(), name


def test_the_measured_tables_are_the_scripts_output_for_every_task() -> None:
    measure = _script("control_suite_exactness")
    results = json.loads((GENERATED / "control_suite_exactness.json").read_text())
    assert [row["task"] for row in results["exactness"]] == list(CONTROL_SUITE_TASKS)
    assert [row["task"] for row in results["drift"]] == list(CONTROL_SUITE_TASKS)
    assert all(row["worst"] <= CHECK_TOLERANCE for row in results["exactness"]), "the page says every task passes"
    assert all(row["steps"] == 1000 for row in results["drift"]), "the page says a whole episode"
    assert results["versions"]["torchtasks side"]["mujoco"] == "4.0.0"
    assert results["versions"]["dm_control side"]["mujoco"] == "3.17.0"
    assert results["date"] in PAGE.read_text(encoding="utf-8"), "the page names the run's date"
    exactness = (GENERATED / "control_suite_exactness_table.md").read_text()
    drift = (GENERATED / "control_suite_drift_table.md").read_text()
    assert exactness == measure.exactness_table(results["exactness"])
    assert drift == measure.drift_table(results["drift"])


def test_the_cheetah_numbers_are_the_scripts_output() -> None:
    results = json.loads((GENERATED / "cheetah_settling.json").read_text())
    page = PAGE.read_text(encoding="utf-8")
    assert results["date"] in page
    assert f"agree to\n  {results['largest_qpos_difference']:.1e} in `qpos`" in page
    assert f"(median {results['median_qpos_difference']:.1e}: the MuJoCo versions)" in page
    assert results["largest_qpos_difference"] < 1e-12  # the preset settles as dm_control does
    assert f"differ by up\n  to {results['largest_qpos_difference_without_the_first_step']:.2f}" in page
    assert f"(median {results['median_qpos_difference_without_the_first_step']:.2f})" in page
