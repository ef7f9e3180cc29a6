"""CommandTrackingTask and velocity_tracking_task on hand-built states: the reward's input, the goal slot, the terms
against their formulas with IsaacLab's weights times dt, the named terminations (a torso contact, a tilted gravity
vector, NaN), and one compiled transition equal to the eager one."""

from __future__ import annotations

import math

import pytest
import torch

from torchtasks.rewards import SquaredSumReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import (
    VELOCITY_TRACKING_WEIGHTS,
    CommandTrackingTask,
    velocity_tracking_state,
    velocity_tracking_task,
)

DT = 0.02
LAYOUT = velocity_tracking_state(num_joints=2, num_feet=2, num_undesired=2)
LABELS = [label for labels in LAYOUT.values() for label in labels]


def _task():
    return velocity_tracking_task(Box([-1.0] * 2, [1.0] * 2), num_joints=2, num_feet=2, num_undesired=2, dt=DT)


def _state(**values):
    state = torch.zeros(1, len(LABELS), dtype=torch.float64)
    state[0, LABELS.index("gravity_z")] = -1.0
    for label, value in values.items():
        state[0, LABELS.index(label)] = value
    return state


def test_the_reward_sees_state_command_and_error_and_the_goal_slot_is_the_tracked_entries():
    spec = EnvSpec(Box.unbounded(3, labels=["a", "b", "c"]), 1)
    # the reward input: [a, b, c, command_c, command_a, error_c, error_a]; the term reads error_c and command_c
    task = CommandTrackingTask(spec, ["c", "a"], SquaredSumReward([5, 3]), command=[1.0, 2.0])
    assert task.reward_space.labels == ("a", "b", "c", "command_c", "command_a", "error_c", "error_a")
    (slot,) = task.goal_slots
    assert (slot.name, slot.size, slot.state_indices) == ("state_des", 2, (2, 0))
    state = torch.tensor([[0.5, 9.0, 0.25]], dtype=torch.float64)
    memory = task.reset(state)  # the constructor's command: (c*, a*) = (1, 2)
    reward, _ = task.step_reward(state, torch.zeros(1, 1, dtype=torch.float64), memory)
    assert reward.tolist() == [(1.0 - 0.25) ** 2 + 1.0**2]  # error_c² + command_c²
    reward, _ = task.step_reward(
        state, torch.zeros(1, 1, dtype=torch.float64), memory, goal=torch.tensor([[0.25, -1.0]])
    )
    assert reward.tolist() == [0.0 + 0.25**2]


def test_terms_are_the_formulas_times_isaaclab_weights_times_dt():
    task = _task()
    velocity = {"lin_vel_x": 0.4, "lin_vel_y": -0.1, "lin_vel_z": 0.2, "ang_vel_x": 0.3, "ang_vel_y": -0.5}
    state = _state(
        **velocity,
        ang_vel_z=0.7,
        gravity_x=0.1,
        gravity_y=-0.2,
        joint_torque_0=3.0,
        joint_torque_1=-4.0,
        undesired_contact_0=5.0,
        undesired_contact_1=0.5,
    )
    command = torch.tensor([[0.5, 0.0, 1.0]], dtype=torch.float64)
    action = torch.tensor([[0.5, -1.0]], dtype=torch.float64)
    out = task.transition(state, action, state, task.reset(state), goal=command)
    w = {name: rate * DT for name, rate in VELOCITY_TRACKING_WEIGHTS.items()}
    expected = {
        "track_lin_vel_xy": w["track_lin_vel_xy"] * math.exp(-((0.5 - 0.4) ** 2 + 0.1**2) / 0.25),
        "track_ang_vel_z": w["track_ang_vel_z"] * math.exp(-((1.0 - 0.7) ** 2) / 0.25),
        "lin_vel_z": w["lin_vel_z"] * 0.2**2,
        "ang_vel_xy": w["ang_vel_xy"] * (0.3**2 + 0.5**2),
        "joint_torques": w["joint_torques"] * (9.0 + 16.0),
        "action_rate": w["action_rate"] * (0.25 + 1.0),  # the previous action is 0 after a reset
        "feet_air_time": 0.0,  # no foot has been in the air
        "undesired_contacts": w["undesired_contacts"] * 1.0,  # 5 N > 1 N, 0.5 N is not
        "flat_orientation": w["flat_orientation"] * (0.1**2 + 0.2**2),
    }
    assert set(out.terms) == set(expected)
    for name, value in expected.items():
        assert out.terms[name].item() == pytest.approx(value, rel=1e-12, abs=1e-18), name
    assert out.reward.item() == pytest.approx(sum(expected.values()), rel=1e-12)
    assert not out.failure.item()


def test_terminations_on_a_torso_contact_a_tilt_and_nan():
    task = _task()
    tilt = math.radians(75.0)  # beyond the 70° limit; 65° is within
    states = torch.cat(
        [
            _state(),
            _state(base_contact=30.0),
            _state(gravity_x=math.sin(tilt), gravity_z=-math.cos(tilt)),
            _state(gravity_x=math.sin(math.radians(65.0)), gravity_z=-math.cos(math.radians(65.0))),
            _state(lin_vel_x=math.nan),
            _state(base_contact=1.0),  # at the threshold: not above it
        ]
    )
    memory = task.reset(states)
    out = task.transition(
        states, torch.zeros(6, 2, dtype=torch.float64), states, memory, goal=torch.zeros(6, 3, dtype=torch.float64)
    )
    assert out.failure.tolist() == [False, True, True, False, True, False]
    assert out.ended_by["base_contact"].tolist() == [False, True, False, False, False, False]
    assert out.ended_by["bad_orientation"].tolist() == [False, False, True, False, False, False]
    assert out.ended_by["out_of_bounds"].tolist() == [False, False, False, False, True, False]
    assert not out.success.any()


def test_bad_task_arguments_are_refused():
    with pytest.raises(ValueError, match="unknown terms"):
        velocity_tracking_task(
            Box([-1.0], [1.0]), num_joints=1, num_feet=1, num_undesired=1, dt=DT, weights={"track_speed": 1.0}
        )
    spec = EnvSpec(Box.unbounded(2, labels=["a", "b"]), 1)
    with pytest.raises(ValueError, match="low <= high"):
        CommandTrackingTask(spec, ["a"], SquaredSumReward([0]), terminations={"bad": ("b", 1.0, 0.0)})
    with pytest.raises(ValueError, match="unknown label 'z'"):
        CommandTrackingTask(spec, ["z"], SquaredSumReward([0]))
    with pytest.raises(ValueError, match="command must have 1 entries"):
        CommandTrackingTask(spec, ["a"], SquaredSumReward([0]), command=[0.0, 1.0])


def test_a_compiled_transition_equals_the_eager_one():
    torch._dynamo.reset()
    task = _task()
    generator = torch.Generator().manual_seed(0)
    states = torch.randn(4, 3, len(LABELS), generator=generator, dtype=torch.float64).abs()
    states[..., LABELS.index("gravity_z")] = -1.0
    states[..., LABELS.index("base_contact")] = 0.0
    actions = torch.randn(3, 3, 2, generator=generator, dtype=torch.float64)
    goal = torch.randn(3, 3, generator=generator, dtype=torch.float64)
    remaining = torch.zeros((), dtype=torch.long)

    def step(state, action, next_state, memory, goal):
        out = task._transition(state, action, next_state, task.with_goal(memory, goal, state), remaining)
        return out.reward, out.done, out.memory

    compiled = torch.compile(step, fullgraph=True, backend="aot_eager")
    eager_memory = compiled_memory = task.reset(states[0])
    for t in range(3):
        args = (states[t], actions[t], states[t + 1])
        eager = step(*args, eager_memory, goal)
        result = compiled(*args, compiled_memory, goal)
        torch.testing.assert_close(result[0], eager[0], rtol=0, atol=0)
        assert torch.equal(result[1], eager[1])
        eager_memory, compiled_memory = eager[2], result[2]
        for key in ("reward", "feet_air_time", "air_time"), ("reward", "action_rate", "last_action"), ("state_des",):
            assert torch.equal(compiled_memory[key], eager_memory[key]), key
