"""PointMassEnv: specs, dynamics (semi-implicit Euler, force clip, walls), resets (uniform in the box at rest; partial
resets touch only the envs asked for), seeding, gradients through env.rollout, and a goal-reaching task on top."""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs import Compose, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchtasks.envs import PointMassEnv
from torchtasks.envs.point_mass import point_mass_dynamics
from torchtasks.rewards import ConstantReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import GoalCommand, TaskTransform


@pytest.mark.parametrize("batch_size", [(), (3,), (2, 3)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_specs(batch_size, dtype):
    env = PointMassEnv(batch_size=batch_size, seed=0, dtype=dtype)
    check_env_specs(env, seed=0)
    td = env.rollout(5)
    assert td["observation"].shape == (*batch_size, 5, 4) and td["observation"].dtype == dtype
    assert td["action"].shape == (*batch_size, 5, 2)
    assert env.action_spec.space.low.min() == -1.0 and env.action_spec.space.high.max() == 1.0
    assert not td["next", "done"].any() and (td["next", "reward"] == 0).all()  # the task decides


def test_reset_is_uniform_in_the_box_at_rest():
    env = PointMassEnv(batch_size=[4000], seed=0, bound=0.5)
    state = env.reset()["observation"]
    position, velocity = state[:, :2], state[:, 2:]
    assert (position.abs() <= 0.5).all() and (velocity == 0).all()
    assert position.min() < -0.49 and position.max() > 0.49  # covers the box
    assert position.mean(0).abs().max() < 0.03 and (position.std(0) - 0.5 / 3**0.5).abs().max() < 0.02


def test_dynamics_semi_implicit_euler_clip_and_walls():
    env = PointMassEnv(batch_size=[3], seed=0, dt=0.1, max_force=1.0, damping=0.5)
    state = torch.tensor([[0.0, 0.0, 1.0, -2.0], [0.0, 0.5, 0.0, 0.0], [0.99, -0.99, 1.0, -1.0]])
    td = TensorDict({"observation": state, "action": torch.tensor([[0.5, 0.0], [5.0, -5.0], [0.0, 0.0]])}, [3])
    nxt = env.step(td)["next", "observation"]
    # env 0: v = v + dt (F - c v), p = p + dt v_new
    v = torch.tensor([1.0 + 0.1 * (0.5 - 0.5), -2.0 + 0.1 * (0.0 + 1.0)])
    torch.testing.assert_close(nxt[0], torch.cat((0.1 * v, v)))
    # env 1: the force is clipped to ±1
    torch.testing.assert_close(nxt[1], torch.tensor([0.01, 0.49, 0.1, -0.1]))
    # env 2: both axes hit the walls: clamped, and the velocity into the wall is zero
    torch.testing.assert_close(nxt[2], torch.tensor([1.0, -1.0, 0.0, 0.0]))
    torch.testing.assert_close(point_mass_dynamics(state, td["action"].clamp(-1, 1), dt=0.1), nxt)


def test_partial_resets_only_touch_the_envs_asked_for():
    env = PointMassEnv(batch_size=[5], seed=1)
    td = env.reset()
    for _ in range(3):
        td = env.step_mdp(env.rand_step(td))
    before = td["observation"].clone()
    assert (before[:, 2:] != 0).all()
    mask = torch.tensor([True, False, True, False, False]).unsqueeze(-1)
    td.set("_reset", mask)
    after = env.reset(td)["observation"]
    assert torch.equal(after[~mask[:, 0]], before[~mask[:, 0]])
    assert (after[mask[:, 0]] != before[mask[:, 0]]).all(-1).all()
    assert (after[mask[:, 0], 2:] == 0).all()


def test_reproducible_with_set_seed():
    first, second = PointMassEnv(batch_size=[4]), PointMassEnv(batch_size=[4])
    first.set_seed(3)
    second.set_seed(3)
    actions = torch.randn(6, 4, 2)
    states = []
    for env in (first, second):
        td = env.reset()
        trajectory = [td["observation"]]
        for action in actions:
            td = env.step_mdp(env.step(td.set("action", action)))
            trajectory.append(td["observation"])
        states.append(torch.stack(trajectory))
    assert torch.equal(states[0], states[1])
    other = PointMassEnv(batch_size=[4], seed=4)
    assert not torch.equal(other.reset()["observation"], states[0][0])
    assert torch.equal(PointMassEnv(batch_size=[4], seed=3).reset()["observation"], states[0][0])


def test_gradients_flow_through_rollout_from_actions_to_states():
    torch.manual_seed(0)
    env = PointMassEnv(batch_size=[8], seed=0, dtype=torch.float64, max_force=1e6)  # no force clipping
    policy = TensorDictModule(torch.nn.Linear(4, 2, dtype=torch.float64), in_keys=["observation"], out_keys=["action"])
    with torch.no_grad():
        policy.module.weight.mul_(0.1)  # small forces: few masses reach a wall (where the gradient is blocked)
    data = env.rollout(10, policy, auto_cast_to_device=False)
    final = data["next", "observation"][:, -1]
    loss = final[:, :2].square().sum()
    loss.backward()
    grad = policy.module.weight.grad
    assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0

    # the gradient from an action to a later position is dt² per step of the remaining horizon (damping 0)
    env = PointMassEnv(batch_size=[1], seed=0, dtype=torch.float64, damping=0.0, bound=100.0, max_force=10.0)
    actions = torch.zeros(4, 1, 2, dtype=torch.float64, requires_grad=True)
    td = env.reset()
    for action in actions:
        td = env.step_mdp(env.step(td.set("action", action)))
    td["observation"][0, 0].backward()
    dt = env.dt
    expected = torch.tensor([4, 3, 2, 1], dtype=torch.float64) * dt**2
    torch.testing.assert_close(actions.grad[:, 0, 0], expected)
    assert (actions.grad[:, 0, 1] == 0).all()


def test_goal_reaching_task_with_a_goal_command():
    inf = float("inf")
    spec = EnvSpec(Box([-1.0, -1.0, -inf, -inf], [1.0, 1.0, inf, inf], labels=PointMassEnv.labels), 2)
    near = functools.partial(proximity_succeeded, threshold=0.1)
    inner = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], ConstantReward(-1.0), success=near)
    task = FinalRewardTask(MaskedTask(spec, inner, ["x", "y"]), factor=1.0)
    transforms = Compose(
        StepCounter(60),
        TaskTransform(task, goal_key="goal", achieved_goal_key="achieved_goal"),
        GoalCommand(Box([-0.8, -0.8], [0.8, 0.8]), seed=0),
    )
    env = TransformedEnv(PointMassEnv(batch_size=[6], seed=0, max_force=2.0), transforms)
    check_env_specs(env, seed=0)

    def go_to_goal(td):  # a PD controller towards the goal the policy sees
        state, goal = td["observation"], td["goal"]
        return td.set("action", (8.0 * (goal - state[..., :2]) - 4.0 * state[..., 2:]).clamp(-2, 2))

    data = env.rollout(60, go_to_goal, break_when_any_done=False)
    assert torch.equal(data["next", "achieved_goal"], data["next", "observation"][..., :2])
    assert data["next", "success"].any(1).all()  # every mass reaches its goal
    distance = (data["next", "achieved_goal"] - data["goal"]).norm(dim=-1, keepdim=True)
    assert torch.equal(data["next", "success"], distance < 0.1)
