"""The Control Suite presets against dm_control itself, and their physics against plain MuJoCo.

- Every preset, on the states of its own rollouts (random actions beyond the bounds, partial resets with new targets):
  dm_control's step from each state (dm-control 1.0.50 on MuJoCo 3.17.0, in the reference venv) gives the preset's
  reward, observation entries and next state, and each reset state gives its observation
  (:func:`~torchtasks.envs.control_suite.check.compare_with_dm_control`, what ``torchtasks check`` runs).
- Every preset's trajectory equals per-env ``MjData`` stepped with ``mj_step`` + ``mj_step1`` under MuJoCo 4.0.0 on
  each env's own model (its drawn targets included), bit for bit.
- The reward is one code path: the task evaluated offline on the rollout's state entries is the online reward.
- Names, the flat observation, checkpoints and bad input.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
import torch
from torchrl.envs.utils import step_mdp

from torchtasks.envs.control_suite import (
    CONTROL_SUITE_TASKS,
    control_suite_base_env,
    control_suite_env,
    control_suite_record,
    control_suite_task,
)
from torchtasks.envs.control_suite.check import CHECK_TOLERANCE, compare_with_dm_control, passed
from torchtasks.transforms import BaseEnvState

pytestmark = pytest.mark.xdist_group("dm_control_reference")


@pytest.mark.dm_control_reference
@pytest.mark.parametrize("name", CONTROL_SUITE_TASKS)
def test_every_preset_equals_dm_control_state_by_state(name: str, dm_control_reference) -> None:
    row = compare_with_dm_control(name, dm_control_reference, num_envs=2, steps=24, seed=1, reset_every=8)
    assert row["states"] > 2 * 24, row  # every step of every env, and the resets
    assert passed(row), row
    # the formulas agree to float64 rounding: the only larger differences are the physics' (two MuJoCo versions)
    assert row["reward"] <= 1e-12, row
    assert max(row["reset_observation"].values()) <= 1e-12, row
    assert CHECK_TOLERANCE <= 1e-8


def _step_reference(model: mujoco.MjModel, data: mujoco.MjData, action: np.ndarray, substeps: int) -> None:
    data.ctrl[:] = action
    mujoco.mj_step(model, data, substeps)
    mujoco.mj_step1(model, data)


@pytest.mark.parametrize("name", CONTROL_SUITE_TASKS)
def test_trajectories_equal_mujoco_per_env_bit_for_bit(name: str) -> None:
    env = control_suite_env(name, 2, seed=3)
    base = env.base_env
    td = env.reset()
    batch = base.batch
    # each env's own model (its drawn targets included) and an MjData started from its reset state
    models = [batch.get_model(i) for i in range(2)]
    datas = []
    for i, model in enumerate(models):
        data = mujoco.MjData(model)
        data.qpos[:], data.qvel[:], data.time = batch.bind("qpos")[i], batch.bind("qvel")[i], batch.bind("time")[i]
        if model.na:
            data.act[:] = batch.bind("act")[i]
        data.qacc_warmstart[:] = batch.bind("qacc_warmstart")[i]  # cheetah's reset ends with 200 settling steps
        mujoco.mj_forward(model, data)
        datas.append(data)
    rng = np.random.default_rng(0)
    low, high = base.model.actuator_ctrlrange.T
    for _ in range(8):
        action = rng.uniform(low, high, size=(2, base.model.nu))
        td["action"] = torch.from_numpy(action)
        td = step_mdp(env.step(td))
        for i, (model, data) in enumerate(zip(models, datas, strict=True)):
            _step_reference(model, data, action[i], base.frame_skip)
            for field in ("qpos", "qvel", "act", "time"):
                np.testing.assert_array_equal(np.atleast_1d(batch.bind(field)[i]), np.atleast_1d(getattr(data, field)))
    env.close()


@pytest.mark.parametrize("name", ["walker-walk", "manipulator-bring_ball"])
def test_reward_offline_equals_online_with_its_terms(name: str) -> None:
    env = control_suite_env(name, 3, seed=0)
    rollout = env.rollout(20, break_when_any_done=False)
    task = control_suite_task(name)
    keys = list(env.base_env.state_layout)
    state = torch.cat([rollout["next", key] for key in keys], dim=-1).reshape(
        -1, sum(env.base_env.state_layout.values())
    )
    action = rollout["action"].reshape(state.shape[0], -1)
    offline = task.reward(state, action)
    torch.testing.assert_close(offline, rollout["next", "reward"].reshape(-1), rtol=0, atol=0)
    env.close()


def test_names_and_the_flat_observation() -> None:
    assert len(CONTROL_SUITE_TASKS) == 30 and len(set(CONTROL_SUITE_TASKS)) == 30
    assert control_suite_record(("ball_in_cup", "catch")) is control_suite_record("ball_in_cup-catch")
    entries = control_suite_env("finger-turn_hard", 2, seed=4)
    flat = control_suite_env("finger-turn_hard", 2, seed=4, flat_observation=True)

    def policy(td):  # the same actions for both
        return td.set("action", torch.full((2, 2), 0.3, dtype=torch.float64))

    a, b = (env.rollout(5, policy, break_when_any_done=False) for env in (entries, flat))
    keys = list(entries.base_env.declaration.observation)
    assert keys == ["position", "velocity", "touch", "target_position", "dist_to_target"]  # dm_control's order
    # the same states (same seed, same actions) give the entries concatenated
    torch.testing.assert_close(
        b["next", "observation"], torch.cat([a["next", key] for key in keys], dim=-1), rtol=0, atol=0
    )
    assert a["next", "position"].dtype == torch.float64
    for env in (entries, flat):
        env.close()


@pytest.mark.parametrize(
    ("name", "error", "match"),
    [
        ("walker-wlak", ValueError, r"unknown Control Suite task 'walker-wlak'; did you mean 'walker-walk'"),
        (("walker", "wlak"), ValueError, r"unknown Control Suite task 'walker-wlak'; did you mean 'walker-walk'"),
        (("walker",), TypeError, r"name must be a task name 'domain-task' or a pair \(domain, task\) of str, got"),
        (("walker", 3), TypeError, r"name must be .* got \('walker', 3\)"),
        (7, TypeError, r"name must be .* got 7"),
    ],
)
def test_unknown_names_are_refused_with_the_closest(name: object, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        control_suite_env(name, 1)  # type: ignore[arg-type]


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(TypeError, match="flat_observation must be a bool"):
        control_suite_base_env("cartpole-swingup", 1, flat_observation="yes")  # type: ignore[arg-type]
    with pytest.raises((TypeError, ValueError), match="num_envs"):
        control_suite_env("cartpole-swingup", 0)


def test_a_checkpoint_continues_targets_and_episodes_bit_for_bit() -> None:
    def make() -> torch.nn.Module:
        env = control_suite_env("reacher-easy", 3, seed=5)
        env.append_transform(BaseEnvState())
        return env

    env = make()
    td = env.reset()
    rng = np.random.default_rng(1)
    actions = torch.from_numpy(rng.uniform(-1, 1, size=(40, 3, 2)))
    for t in range(10):
        td["action"] = actions[t]
        td = step_mdp(env.step(td))
    saved = copy.deepcopy(env.state_dict())
    resumed = make()
    resumed.load_state_dict(saved)
    other = td.clone()
    targets = env.base_env.domain_values(["geom_pos:target"])["geom_pos:target"]
    torch.testing.assert_close(resumed.base_env.domain_values(["geom_pos:target"])["geom_pos:target"], targets)
    for t in range(10, 40):
        if t == 25:  # a partial reset draws new targets from each env's saved generator
            for each in (td, other):
                each["_reset"] = torch.tensor([[True], [False], [True]])
            td, other = env.reset(td), resumed.reset(other)
        td["action"], other["action"] = actions[t], actions[t]
        a = env.step(td)
        if t == 10:  # the tensordict carries the running episodes here (the warning is for collectors)
            with pytest.warns(UserWarning, match="stepped after load_state_dict without a reset"):
                b = resumed.step(other)
        else:
            b = resumed.step(other)
        for key in ("to_target", "reward", "episode_reward"):
            torch.testing.assert_close(a["next", key], b["next", key], rtol=0, atol=0)
        td, other = step_mdp(a), step_mdp(b)
    after = env.base_env.domain_values(["geom_pos:target"])["geom_pos:target"]
    assert not torch.equal(after[0], targets[0]) and torch.equal(after[1], targets[1])
    for e in (env, resumed):
        e.close()


def _reset_twice(env) -> tuple:
    """A full reset, then a partial one of env 0: its observation and every domain value after."""
    td = env.reset()
    td = env.reset(td.set("_reset", torch.tensor([[True], [False]])))
    return td, env.domain_values()


@pytest.mark.parametrize("name", ["manipulator-bring_ball", "quadruped-run"])
def test_copies_and_pickles_continue_with_their_reset_steps(name: str) -> None:
    """A copy or an unpickled env (a spawned worker's) rebuilds the reset steps and continues bit for bit."""
    import pickle

    env = control_suite_base_env(name, 2, seed=2)
    env.reset()
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    first, values = _reset_twice(env)
    for other in copies:
        td, other_values = _reset_twice(other)
        for key in env.declaration.observation:
            torch.testing.assert_close(td[key], first[key], rtol=0, atol=0)
        for field, value in values.items():
            torch.testing.assert_close(other_values[field], value, rtol=0, atol=0)
        other.close()
    env.close()
