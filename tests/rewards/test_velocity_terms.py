"""The velocity-tracking reward terms against their definitions, written here by hand (Python floats).

ExpTrackingReward ``exp(-Σ e²/std²)``, SquaredSumReward ``Σ x²``, ContactCountReward ``Σ [f > threshold]``,
ActionRateReward ``Σ (a - a_prev)²`` with the previous action in memory, FeetAirTimeReward (air time per foot in
memory, paid at landing, gated by the command), with partial resets done as TaskTransform does them.
"""

from __future__ import annotations

import math

import pytest
import torch

from torchtasks.rewards import (
    ActionRateReward,
    ContactCountReward,
    ExpTrackingReward,
    FeetAirTimeReward,
    SquaredSumReward,
)
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import GoallessTask
from torchtasks.tasks.memory import where_memory

STATE = [[0.3, -0.4, 2.0, 7.0], [1.5, 0.0, -1.0, 0.5]]


def test_exp_tracking_reward_is_the_kernel_of_the_selected_errors():
    reward = ExpTrackingReward(0.5, indices=["ex", "ey"], space=Box.unbounded(4, labels=["ex", "z", "ey", "w"]))
    value = reward(torch.tensor(STATE, dtype=torch.float64), None)
    expected = [math.exp(-(row[0] ** 2 + row[2] ** 2) / 0.25) for row in STATE]
    assert value.tolist() == pytest.approx(expected, rel=1e-15, abs=0)
    assert value.dtype == torch.float64
    # differentiable: d/de exp(-e²/s²) = -2e/s² exp(-e²/s²)
    state = torch.tensor(STATE, dtype=torch.float64, requires_grad=True)
    reward(state, None).sum().backward()
    assert state.grad[0, 0].item() == pytest.approx(-2 * 0.3 / 0.25 * expected[0], rel=1e-12)
    assert state.grad[:, [1, 3]].abs().sum().item() == 0.0


def test_squared_sum_and_contact_count():
    state = torch.tensor(STATE, dtype=torch.float64)
    assert SquaredSumReward([0, 3])(state, None).tolist() == [0.3**2 + 7.0**2, 1.5**2 + 0.5**2]
    count = ContactCountReward(0.5, indices=[0, 2, 3])(state, None)
    assert count.tolist() == [2.0, 1.0]  # 0.5 is not above 0.5
    assert ContactCountReward(0.0, [0])(torch.tensor([[math.nan]]), None).tolist() == [0.0]


@pytest.mark.parametrize(
    ("build", "error", "match"),
    [
        (lambda: ExpTrackingReward(0.0, [0]), ValueError, "std must be positive"),
        (lambda: SquaredSumReward([]), ValueError, "at least one state entry"),
        (lambda: SquaredSumReward(["vz"]), TypeError, "pass the space"),
        (lambda: ContactCountReward(1.0, [1, 1]), ValueError, "duplicates"),
        (lambda: FeetAirTimeReward(0.0, [0]), ValueError, "dt must be positive"),
        (lambda: ActionRateReward(0), ValueError, "action_size must be a positive int"),
    ],
)
def test_bad_arguments_are_refused(build, error, match):
    with pytest.raises(error, match=match):
        build()


def test_a_task_refuses_terms_that_read_beyond_its_state():
    with pytest.raises(ValueError, match=r"reads state entries indices=\[4\], but the task's state has 4 entries"):
        GoallessTask(EnvSpec(4, 2), SquaredSumReward([4]))
    with pytest.raises(ValueError, match="expects actions of size 3"):
        GoallessTask(EnvSpec(4, 2), ActionRateReward(3))


def test_action_rate_keeps_the_previous_action_and_starts_from_zero():
    reward = ActionRateReward(2)
    state = torch.zeros(2, 1, dtype=torch.float64)
    memory = reward.reset(state)
    actions = [[[1.0, 2.0], [0.0, -1.0]], [[1.5, 2.0], [3.0, 3.0]]]
    previous = [[0.0, 0.0], [0.0, 0.0]]
    for step in actions:
        value, memory = reward.step(state, torch.tensor(step, dtype=torch.float32), memory)
        expected = [
            sum((a - b) ** 2 for a, b in zip(row, last, strict=True)) for row, last in zip(step, previous, strict=True)
        ]
        assert value.tolist() == expected and value.dtype == torch.float64
        previous = step
    assert memory["last_action"].tolist() == actions[-1] and memory["last_action"].dtype == torch.float64


def _air_time_reference(touches, commands, dt, threshold, contact, min_command, resets):
    """Per env, per step: the reward from the definition, with air times kept in Python lists."""
    envs, feet = len(touches[0]), len(touches[0][0])
    air = [[0.0] * feet for _ in range(envs)]
    rewards = []
    for t, step in enumerate(touches):
        row = []
        for e in range(envs):
            if resets[t][e]:
                air[e] = [0.0] * feet
            value = 0.0
            for f in range(feet):
                in_contact = step[e][f] > contact
                if in_contact and air[e][f] > 0:
                    value += air[e][f] - threshold
                air[e][f] = 0.0 if in_contact else air[e][f] + dt
            moving = math.hypot(*commands[t][e]) > min_command
            row.append(value if moving else 0.0)
        rewards.append(row)
    return rewards


def test_feet_air_time_with_partial_resets():
    """Two feet, three envs, 8 steps; env 1 is reset before step 4 (mid-swing), env 2 is told to stand at step 6."""
    generator = torch.Generator().manual_seed(0)
    steps, envs = 8, 3
    touches = (torch.rand(steps, envs, 2, generator=generator) > 0.45).double() * 5.0
    commands = torch.full((steps, envs, 2), 0.5, dtype=torch.float64)
    commands[6:, 2] = 0.0
    resets = torch.zeros(steps, envs, dtype=torch.bool)
    resets[4, 1] = True
    dt, threshold = 0.02, 0.03
    reward = FeetAirTimeReward(dt, [0, 1], threshold=threshold, contact_threshold=1.0, command_indices=[2, 3])
    memory = None
    values = []
    for t in range(steps):
        state = torch.cat((touches[t], commands[t]), dim=-1)
        fresh = reward.reset(state)
        memory = fresh if memory is None else where_memory(resets[t], fresh, memory)  # as TaskTransform resets
        value, memory = reward.step(state, None, memory)
        values.append(value.tolist())
    expected = _air_time_reference(touches.tolist(), commands.tolist(), dt, threshold, 1.0, 0.1, resets.tolist())
    for t in range(steps):
        assert values[t] == pytest.approx(expected[t], rel=1e-12, abs=1e-15), t
    assert any(value != 0 for row in expected for value in row)  # some landings were paid
