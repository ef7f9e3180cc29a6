"""The training examples run end to end in ``--quick`` mode and write their learning curves.

``examples/train_swingup_ppo.py`` (PPO), ``examples/differentiable_shaping.py`` (analytic
policy gradients), ``examples/train_locomotion_ppo.py`` (PPO on MuJoCo HalfCheetah, needs the
``mujoco`` extra), ``examples/train_safety_ppo_lagrangian.py``,
``examples/train_hopper_domain_randomization.py`` (PPO on Hopper, nominal and with randomized masses
and frictions, evaluated on a grid of models), ``examples/own_robot_ppo.py`` (PPO on the shipped quadruped),
``examples/control_suite_ppo.py`` (PPO on a DeepMind Control Suite preset),
``examples/velocity_tracking_ppo.py`` (PPO on the velocity-tracking quadruped)
and ``examples/train_multi_objective_ppo.py`` (PPO with
one critic per reward group on ``mo-halfcheetah-v5``, a front over weight vectors) are run as scripts,
as a user would, from a fresh empty directory with their default outputs (``runs/<example name>/``;
:func:`run_quick` also checks that nothing else appears there). The quick runs take a few seconds
each; they check the code paths (training, evaluation, JSON, PNG, the PPO comparison), not the learning.
"""

from __future__ import annotations

import importlib.util
import json
import math
import shutil
import statistics
import subprocess
from pathlib import Path
from typing import Any

import pytest

from example_runs import run_quick
from torchtasks.tasks import VELOCITY_TRACKING_WEIGHTS

TIMEOUT_S = 120  # a quick run takes < 60 s on the 2-core CI machine, even when it is busy

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("examples")]

RUN_FIELDS = {
    "method",
    "config",
    "seed",
    "target",
    "curve",
    "time_to_target_s",
    "frames_to_target",
    "total_frames",
    "total_seconds",
    "final_success_rate",
    "final_episode_reward",
    "machine_start",
    "machine_end",
}
POINT_FIELDS = {"iteration", "frames", "seconds", "eval_success_rate", "eval_episode_reward", "eval_episode_length"}


def run_example(script: str, cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``examples/<script> --quick <args>`` from the empty folder ``cwd`` (see :func:`run_quick`)."""
    result = run_quick(script, cwd, *args, timeout=TIMEOUT_S)
    info = [line for line in (result.stdout + result.stderr).splitlines() if "[torchrl][INFO]" in line]
    assert not info, f"TorchRL INFO logs in {script}'s output (the examples quiet them): {info[:3]}"
    return result


def load_run(path: Path) -> dict[str, Any]:
    """Read a run record and check the fields every training example writes."""
    assert path.is_file(), f"{path} was not written"
    record = json.loads(path.read_text())
    assert RUN_FIELDS <= record.keys(), f"missing fields: {RUN_FIELDS - record.keys()}"
    assert record["curve"], "the learning curve is empty"
    for point in record["curve"]:
        assert POINT_FIELDS <= point.keys(), f"missing curve fields: {POINT_FIELDS - point.keys()}"
        assert 0.0 <= point["eval_success_rate"] <= 1.0
    frames = [point["frames"] for point in record["curve"]]
    assert frames == sorted(frames) and frames[-1] == record["total_frames"] > 0
    return record


@pytest.fixture(scope="module")
def ppo_output(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The output directory of one quick PPO run: its default, ``runs/train_swingup_ppo/quick/``."""
    cwd = tmp_path_factory.mktemp("ppo")
    run_example("train_swingup_ppo.py", cwd, "--seed", "1")
    return cwd / "runs" / "train_swingup_ppo" / "quick"


def test_ppo_quick_writes_curve_json_and_png(ppo_output: Path) -> None:
    record = load_run(ppo_output / "swingup_ppo_curve.json")
    assert record["method"] == "PPO"
    assert record["seed"] == 1
    assert record["target"] == 0.8
    assert {"train_success_rate", "train_episode_reward"} <= record["curve"][-1].keys()
    assert (ppo_output / "swingup_ppo_curve.png").stat().st_size > 0


def test_differentiable_shaping_quick_writes_curve_and_comparison(ppo_output: Path, tmp_path: Path) -> None:
    """By default it compares with the PPO run where ``train_swingup_ppo.py`` writes it by default (a quick run
    with a quick run)."""
    ppo_json = tmp_path / "runs" / "train_swingup_ppo" / "quick" / "swingup_ppo_curve.json"
    ppo_json.parent.mkdir(parents=True)
    shutil.copy(ppo_output / "swingup_ppo_curve.json", ppo_json)
    result = run_example("differentiable_shaping.py", tmp_path)
    output = tmp_path / "runs" / "differentiable_shaping" / "quick"
    record = load_run(output / "differentiable_shaping_curve.json")
    assert record["method"] == "analytic gradients"
    assert "loss" in record["curve"][-1]
    assert record["ppo"]["frames_to_target"] == json.loads(ppo_json.read_text())["frames_to_target"]
    assert (output / "differentiable_shaping_curve.png").stat().st_size > 0
    assert "PPO (runs/train_swingup_ppo/quick/swingup_ppo_curve.json)" in result.stdout


def test_differentiable_shaping_quick_without_ppo_run(tmp_path: Path) -> None:
    """``--output`` moves the outputs; with no PPO run there or in the PPO example's folder, none is compared."""
    output = Path("runs", "differentiable_shaping", "seed0")  # relative to the current directory
    result = run_example("differentiable_shaping.py", tmp_path, "--output", str(output))
    record = load_run(tmp_path / output / "differentiable_shaping_curve.json")
    assert "ppo" not in record
    assert "no PPO run at runs/train_swingup_ppo/quick/swingup_ppo_curve.json" in result.stdout


def test_locomotion_ppo_quick_writes_curve_json_and_png(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    result = run_example("train_locomotion_ppo.py", tmp_path, "--seeds", "3")
    output = tmp_path / "runs" / "train_locomotion_ppo" / "quick"  # the default --output of a --quick run
    record = json.loads((output / "locomotion_ppo_seed3.json").read_text())
    assert record["seed"] == 3 and record["env_id"] == "HalfCheetah-v5" and record["method"] == "PPO"
    frames = [point["frames"] for point in record["curve"]]
    assert frames == [2000, 4000] == [2000, record["total_frames"]]
    assert all(point["seconds"] > 0 and point["load_1min"] >= 0 for point in record["curve"])
    # 4 envs x 500 steps per batch: every env's first episode ends (truncated at 1000 steps) in the second batch
    first, last = record["curve"]
    assert first["train_return"] is None and first["episodes"] == 0
    assert last["episodes"] == 4 and last["episode_length_mean"] == 1000 and last["timeout_rate"] == 1
    assert last["train_return"] == pytest.approx(last["train_return/forward"] + last["train_return/ctrl"])
    assert last["train_return/ctrl"] < 0
    assert record["final_train_return"] == last["train_return"] and record["final_train_frames"] == 4000
    (evaluation,) = record["eval_curve"]  # the deterministic evaluation at the end: one 1000-step episode per env
    assert evaluation["complete_episodes"] == 2 and evaluation["episode_length_mean"] == 1000
    terms = evaluation["return_mean/forward"] + evaluation["return_mean/ctrl"]
    assert evaluation["return_mean"] == pytest.approx(terms)
    assert record["final_eval_return"] == evaluation["return_mean"]
    assert record["frames_per_second"] > 0 and record["machine_end"]["load_1min"] >= 0
    assert "seed 3: 4000 frames in" in result.stdout
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "locomotion_ppo_curve.png").stat().st_size > 0
        assert "locomotion_ppo_curve.png (1 seed)" in result.stdout


def test_own_robot_ppo_quick_writes_curve_json_and_png(tmp_path: Path) -> None:
    """PPO on the shipped quadruped (BatchedMujocoEnv of an MJCF file, a task on named readings): every code path."""
    pytest.importorskip("mujoco")
    result = run_example("own_robot_ppo.py", tmp_path, "--seed", "3")
    output = tmp_path / "runs" / "own_robot_ppo" / "quick"  # the default --output of a --quick run
    record = json.loads((output / "own_robot_ppo_seed3.json").read_text())
    assert record["seed"] == 3 and record["model"] == "quadruped" and record["method"] == "PPO"
    assert [point["frames"] for point in record["curve"]] == [200, 400] == [200, record["total_frames"]]
    for point in record["curve"]:  # 4 envs x 50 steps: episodes end only by a fall (the time limit is 500 steps)
        assert point["seconds"] > 0 and point["loss_critic"] >= 0
        if point["episodes"]:
            assert point["failure_rate"] == 1.0
            # the reward is the product of the factors upright in [0, 1] and move in [1/6, 1]: below each of them
            assert 0 <= point["train_return"] <= min(point["train_return/upright"], point["train_return/move"])
    (evaluation,) = record["eval_curve"]  # the deterministic evaluation at the end: 2 envs, up to 500 steps each
    assert evaluation["frames"] == 400 and 1 <= evaluation["episode_length_mean"] <= 500
    assert 0 <= evaluation["return_mean"] <= min(evaluation["return_mean/upright"], evaluation["return_mean/move"])
    assert math.isfinite(evaluation["forward_velocity_mean"])
    assert record["final_eval_return"] == evaluation["return_mean"] == record["first_eval_return"]
    assert record["frames_per_second"] > 0 and record["machine_end"]["load_1min"] >= 0
    assert "seed 3: 400 frames in" in result.stdout
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "own_robot_ppo_curve.png").stat().st_size > 0
        assert "own_robot_ppo_curve.png (1 seed)" in result.stdout


def test_velocity_tracking_ppo_quick_writes_json_table_and_png(tmp_path: Path) -> None:
    """PPO on the velocity-tracking quadruped: the training curve with every reward term, the evaluation's tracking
    errors and falls, each variant under each condition, the markdown table and the plot."""
    pytest.importorskip("mujoco")
    result = run_example("velocity_tracking_ppo.py", tmp_path, "--seeds", "3", "4")
    output = tmp_path / "runs" / "velocity_tracking_ppo" / "quick"  # the default --output of a --quick run
    record = json.loads((output / "velocity_tracking_seed3.json").read_text())
    other = json.loads((output / "velocity_tracking_seed4.json").read_text())
    summary = (output / "velocity_tracking_seeds3-4.md").read_text()  # both seeds: the mean, then each seed's
    falls = [run["results"]["robust"]["nominal"]["falls_per_episode"] for run in (record, other)]
    assert "| robust | nominal | " in summary and f"({falls[0]:.2f} / {falls[1]:.2f})" in summary
    assert f"**{sum(falls) / 2:.2f}**" in summary and "seeds 3, 4" in summary
    assert "velocity_tracking_seeds3-4.md" in result.stdout
    assert record["seed"] == 3 and record["method"] == "PPO" and record["total_seconds"] > 0
    trained = record["variants"]["nominal"]
    assert [point["frames"] for point in trained["curve"]] == [100, 200] == [100, trained["total_frames"]]
    for point in trained["curve"]:  # 4 envs x 25 steps of 1000-step episodes: only falls end them
        assert point["falls"] == point["episodes"] and point["train_lin_vel_error"] >= 0
        assert point["command_high"] is not None and point["command_high"][0] <= 1.0  # the curriculum's range
        if point["train_return"] is not None:
            terms = sum(point[f"train_return/{term}"] for term in VELOCITY_TRACKING_WEIGHTS)
            assert point["train_return"] == pytest.approx(terms)
    (evaluation,) = trained["eval_curve"]  # 2 envs x 30 steps at the end
    assert evaluation["frames"] == 200 and evaluation["episodes"] >= 2
    assert 0 <= evaluation["falls_per_episode"] <= 1 and evaluation["lin_vel_error"] >= 0
    assert set(record["variants"]) == {"nominal", "robust"}  # trained without and with perturbations
    assert record["variants"]["robust"]["total_frames"] == 200
    conditions = {"nominal", "pushes and delay"}
    assert {variant: set(results) for variant, results in record["results"].items()} == dict.fromkeys(
        ("standing still", "nominal", "robust"), conditions
    )
    standing = record["results"]["standing still"]["nominal"]  # zero actions: it stands, the errors are the commands'
    assert standing["falls_per_episode"] == 0 and standing["lin_vel_error"] > 0
    table = (output / "velocity_tracking_seed3.md").read_text()
    assert "| robust | pushes and delay |" in table and "| standing still | nominal |" in table
    assert "nominal, seed 3: 200 frames in" in result.stdout
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "velocity_tracking_seed3.png").stat().st_size > 0
        assert (output / "velocity_tracking_seeds3-4.png").stat().st_size > 0


def test_control_suite_ppo_quick_writes_curve_json_and_png(tmp_path: Path) -> None:
    """PPO on a Control Suite preset (train_locomotion_ppo's loop with another preset): the returns on the papers'
    scale, every reward factor logged per episode, the JSON, the table and the plot."""
    pytest.importorskip("mujoco")
    result = run_example("control_suite_ppo.py", tmp_path, "--task", "cartpole-swingup", "--seeds", "3")
    output = tmp_path / "runs" / "control_suite_ppo" / "quick"  # the default --output of a --quick run
    record = json.loads((output / "cartpole-swingup_seed3.json").read_text())
    assert record["seed"] == 3 and record["task"] == record["env_id"] == "cartpole-swingup"
    assert record["method"] == "PPO" and "flat_observation=True" in record["preset"]
    factors = ("upright", "centered", "small_control", "small_velocity")  # dm_control's cartpole reward, a product
    # 4 envs x 500 steps per batch: every env's first episode ends (truncated at 1000 steps) in the second batch
    first, last = record["curve"]
    assert [first["frames"], last["frames"]] == [2000, 4000] == [2000, record["total_frames"]]
    assert first["train_return"] is None and first["episodes"] == 0
    assert last["episodes"] == 4 and last["episode_length_mean"] == 1000 and last["timeout_rate"] == 1
    # a product of factors in [0, 1] per step: the return is in [0, 1000] and below every factor's episode sum
    assert 0 <= last["train_return"] <= min(last[f"train_return/{factor}"] for factor in factors) <= 1000
    assert record["final_train_return"] == record["best_train_return"] == last["train_return"]
    assert record["best_train_frames"] == record["final_train_frames"] == 4000
    (evaluation,) = record["eval_curve"]  # the deterministic evaluation at the end: one 1000-step episode per env
    assert evaluation["complete_episodes"] == 2 and evaluation["episode_length_mean"] == 1000
    assert 0 <= evaluation["return_mean"] <= min(evaluation[f"return_mean/{factor}"] for factor in factors) <= 1000
    assert record["final_eval_return"] == record["best_eval_return"] == evaluation["return_mean"]
    assert record["frames_per_second"] > 0 and record["machine_end"]["load_1min"] >= 0
    assert "cartpole-swingup seed 3: 4000 frames in" in result.stdout
    assert "| cartpole-swingup | 3 | 4,000 | " in result.stdout  # the table of every run in the folder
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "control_suite_ppo_curve.png").stat().st_size > 0
        assert "control_suite_ppo_curve.png (1 run)" in result.stdout


def test_safety_ppo_lagrangian_quick_writes_runs_and_png(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    result = run_example("train_safety_ppo_lagrangian.py", tmp_path, "--seeds", "3")
    output = tmp_path / "runs" / "train_safety_ppo_lagrangian" / "quick"  # the default --output of a --quick run
    for variant, method in (("lagrangian", "PPO-Lagrangian"), ("ppo", "PPO (λ = 0)")):
        record = json.loads((output / f"{variant}_seed3.json").read_text())
        assert record["seed"] == 3 and record["variant"] == variant and record["method"] == method
        assert record["config"]["cost_limit"] == 25.0
        first, last = record["curve"]
        assert [first["frames"], last["frames"]] == [2000, 4000] == [2000, record["total_frames"]]
        # 4 envs x 500 steps per batch: the episodes end (at step 1000) in the second batch only, and λ moves then
        assert first["train_cost"] is None and first["train_return"] is None
        assert last["train_cost"] >= 0 and 0 <= last["train_violation_rate"] <= 1
        assert last["train_return"] == pytest.approx(last["train_return/forward"] + last["train_return/ctrl"])
        assert last["loss_cost_critic"] >= 0 and last["loss_critic"] >= last["loss_cost_critic"]
        if variant == "lagrangian":
            assert first["lambda"] == pytest.approx(0.001)  # the initial value: no episode had ended
            assert record["multiplier_state"]["steps"] == 1  # one Adam step, at the second batch
            # one Adam step of lr 0.25 against sign(J_c - 25), projected on λ >= 0
            expected = 0.001 + 0.25 if last["train_cost"] > 25 else 0.0
            assert last["lambda"] == pytest.approx(expected, abs=1e-6)
        else:
            assert first["lambda"] == last["lambda"] == record["final_lambda"] == 0.0
            assert record["multiplier_state"]["steps"] == 0
        (evaluation,) = record["eval_curve"]  # one deterministic 1000-step episode per eval env, at the end
        assert evaluation["complete_episodes"] == 2 and evaluation["episode_length_mean"] == 1000
        assert 0 <= evaluation["cost_mean/velocity"] <= 1000
        assert 0 <= evaluation["cost_violation_rate/velocity"] <= 1
        assert record["final_eval_cost"] == evaluation["cost_mean/velocity"]
        assert f"{method} seed 3: 4000 frames in" in result.stdout
    assert "Warning" not in result.stderr
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "safety_ppo_lagrangian_curve.png").stat().st_size > 0
        assert "safety_ppo_lagrangian_curve.png (2 runs)" in result.stdout


def test_hopper_domain_randomization_quick_writes_runs_table_and_png(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    result = run_example("train_hopper_domain_randomization.py", tmp_path, "--seeds", "3")
    output = tmp_path / "runs" / "train_hopper_domain_randomization" / "quick"  # the default --output of --quick
    factors = (0.5, 0.75, 1.0, 1.25, 1.5)
    episodes = 2  # --quick's episodes per grid model
    # env i runs grid point i // 2: mass factors in the outer loop, friction factors in the inner one
    expected_domains = [(mass, friction) for mass in factors for friction in factors for _ in range(episodes)]
    tables = (output / "robustness.md").read_text().split("\n## ")[1:]
    assert [section.splitlines()[0] for section in tables] == ["nominal", "randomized"]
    for variant, section in zip(("nominal", "randomized"), tables, strict=True):
        record = json.loads((output / f"dr_{variant}_seed3.json").read_text())
        assert record["seed"] == 3 and record["variant"] == variant and record["env_id"] == "Hopper-v5"
        assert [point["frames"] for point in record["curve"]] == [400, 800] == [400, record["total_frames"]]
        assert record["seconds"] >= record["total_seconds"] > 0 and record["machine_end"]["load_1min"] >= 0
        # Hopper falls within 100 steps under an untrained policy: training episodes end in every batch
        assert all(point["episodes"] > 0 and point["train_return"] is not None for point in record["curve"])
        drawn_mass = [point.get("domain/body_mass_scale") for point in record["curve"]]
        if variant == "nominal":
            assert record["randomization"] is None and drawn_mass == [None, None]
        else:  # the mean mass factor of the training episodes that ended: drawn from U[0.5, 1.5], not the nominal 1
            assert set(record["randomization"]) == {"body_mass_scale", "geom_friction_scale"}
            assert all(0.5 <= mass <= 1.5 and mass != 1.0 for mass in drawn_mass)
        grid = record["grid_evaluation"]
        envs = grid["envs"]
        assert list(zip(envs["body_mass_scale"], envs["geom_friction_scale"], strict=True)) == expected_domains
        assert grid["episodes_per_point"] == episodes and grid["max_steps"] == 100 and 1 <= grid["steps"] <= 100
        assert len(envs["return"]) == len(envs["length"]) == len(envs["ended"]) == 50
        for length, ended in zip(envs["length"], envs["ended"], strict=True):
            assert 1 <= length <= grid["steps"]
            assert ended or length == grid["steps"] == 100  # an env that never ended ran every step
        assert all(math.isfinite(value) for value in envs["return"])
        means = [statistics.fmean(envs["return"][i : i + episodes]) for i in range(0, 50, episodes)]
        stds = [statistics.pstdev(envs["return"][i : i + episodes]) for i in range(0, 50, episodes)]
        assert [len(row) for row in grid["mean"]] == [len(row) for row in grid["std"]] == [5] * 5
        assert [value for row in grid["mean"] for value in row] == pytest.approx(means)
        assert [value for row in grid["std"] for value in row] == pytest.approx(stds)
        assert grid["grid_mean"] == pytest.approx(statistics.fmean(means))
        # the table: a row per mass factor, a "mean ± std" cell per friction factor, as in the JSON
        rows = [line for line in section.splitlines() if line.startswith("| ") and " ± " in line]
        assert [row.split(" | ")[0] for row in rows] == [f"| {mass:g}" for mass in factors]
        cells = [cell for row in rows for cell in row.strip(" |").split(" | ")[1:]]
        assert len(cells) == 25
        for cell, mean, std in zip(cells, means, stds, strict=True):
            shown_mean, shown_std = (float(part.replace(",", "")) for part in cell.split(" ± "))
            assert shown_mean == pytest.approx(mean, abs=0.051) and shown_std == pytest.approx(std, abs=0.051)
        assert f"{variant} seed 3: 800 frames in" in result.stdout
    assert "robustness.md (2 runs)" in result.stdout
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "robustness.png").stat().st_size > 0
        assert "robustness.png" in result.stdout


def test_multi_objective_ppo_quick_writes_runs_front_and_png(tmp_path: Path) -> None:
    """Two weight vectors (``--quick``'s), one run each; the front holds their last deterministic evaluation."""
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    result = run_example("train_multi_objective_ppo.py", tmp_path, "--seeds", "3")
    output = tmp_path / "runs" / "train_multi_objective_ppo" / "quick"  # the default --output of a --quick run
    front = json.loads((output / "front.json").read_text())
    assert front["env_id"] == "mo-halfcheetah-v5" and front["eval_envs"] == 2 and front["eval_steps"] == 250
    forward, ctrl = front["groups"]  # MO-Gymnasium's objectives: [x_velocity, -Σa²]
    assert [point["weights"] for point in front["points"]] == [[1.0, 0.1], [1.0, 2.0]]
    for point, name in zip(front["points"], ("1_0.1", "1_2"), strict=True):
        record = json.loads((output / f"mo_ppo_w{name}_seed3.json").read_text())
        assert record["seed"] == point["seed"] == 3 and record["weights"] == point["weights"]
        assert record["groups"] == front["groups"]
        # 4 envs x 125 steps per batch, two batches: no 1000-step episode ends, so no training return
        assert [p["frames"] for p in record["curve"]] == [500, 1000] == [500, record["total_frames"]]
        assert all(p["train_return"] is None and p[f"train_return/{ctrl}"] is None for p in record["curve"])
        assert all(p[f"loss_critic/{forward}"] > 0 and p[f"loss_critic/{ctrl}"] > 0 for p in record["curve"])
        (evaluation,) = record["eval_curve"]  # at the end: 2 envs x 250 steps, partial episodes
        assert evaluation["frames"] == 1000 and evaluation["complete_episodes"] == 0
        returns = [evaluation[f"group_return_mean/{group}"] for group in (forward, ctrl)]
        assert point["returns"] == dict(zip((forward, ctrl), returns, strict=True)) == record["final_eval_returns"]
        assert returns[1] < 0  # -Σa² summed over 250 steps of a policy that moves
        # Gymnasium's reward is x_velocity - 0.1 Σa²: the scalar return is the groups scalarised with [1, 0.1]
        assert evaluation["return_mean"] == pytest.approx(returns[0] + 0.1 * returns[1], rel=1e-5, abs=1e-4)
        w0, w1 = point["weights"]
        assert point["weighted_return"] == pytest.approx(w0 * returns[0] + w1 * returns[1])
        assert point["frames"] == 1000 and point["seconds"] == record["total_seconds"] > 0
        assert f"w = {name.replace('_', ',')} seed 3: 1000 frames in" in result.stdout
    table = result.stdout.split("wrote", -1)[-1].splitlines()[1:]  # the table after the last "wrote" line
    assert table[0].split() == ["weights", "seed", forward, ctrl, "w·J", "frames", "time"]
    assert [row.split()[:2] for row in table[1:]] == [["1,0.1", "3"], ["1,2", "3"]]
    assert "front.json (2 runs)" in result.stdout
    if importlib.util.find_spec("matplotlib") is not None:
        assert (output / "front.png").stat().st_size > 0
