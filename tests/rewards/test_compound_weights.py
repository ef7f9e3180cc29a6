"""Per-term weights of CompoundReward (issue 26, item 5): IsaacLab's ``RewardTermCfg(weight=...)``.

The breakdown reports weighted terms (they add up to the reward), unweighted terms and compounds are
unchanged, the weights are float64 buffers named ``weights.<term>`` that a Curriculum schedules.
"""

from __future__ import annotations

import copy
import math

import pytest
import torch
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import CompoundReward, ConstantReward, ForwardVelocityReward, QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import FinalRewardTask, RadiallySymmetricDesiredStateTask
from torchtasks.transforms import Curriculum, TaskTransform, staged


def terms() -> dict[str, object]:
    return {
        "track": QuadraticErrorReward([1.0, 0.5], None),
        "effort": QuadraticErrorReward([0.0, 0.0], [1.0]),
        "forward": ConstantReward(1.0),  # a name of an nn.Module attribute
    }


def inputs() -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(1)
    return torch.randn(5, 2, generator=generator), torch.randn(5, 1, generator=generator)


def test_weighted_terms_are_the_plain_terms_times_their_weights_and_add_up_to_the_reward() -> None:
    plain = CompoundReward(terms())
    weighted = CompoundReward(terms(), weights={"effort": 0.1, "forward": -2.0})
    state, action = inputs()
    expected = plain.terms(state, action)
    got = weighted.terms(state, action)
    assert list(got) == ["track", "effort", "forward"]
    torch.testing.assert_close(got["track"], expected["track"], rtol=0, atol=0)
    torch.testing.assert_close(got["effort"], 0.1 * expected["effort"])
    torch.testing.assert_close(got["forward"], -2.0 * expected["forward"])
    torch.testing.assert_close(weighted(state, action), got["track"] + got["effort"] + got["forward"])
    torch.testing.assert_close(weighted.step_terms(state, action, weighted.reset(state))[0]["effort"], got["effort"])
    assert not torch.allclose(weighted(state, action), plain(state, action))


def test_without_weights_nothing_changes() -> None:
    plain = CompoundReward(terms())
    assert not any(name.startswith("weights.") for name in plain.state_dict())
    state, action = inputs()
    values = {name: reward(state, action) for name, reward in terms().items()}
    assert torch.equal(plain(state, action), values["track"] + values["effort"] + values["forward"])


def test_weights_are_float64_buffers_that_follow_dtype_device_copies_and_state_dicts() -> None:
    reward = CompoundReward(terms(), weights={"effort": 0.1})
    assert [name for name, _ in reward.named_buffers() if name.startswith("weights.")] == ["weights.effort"]
    assert reward.weights._buffers["effort"].dtype == torch.float64
    state, action = inputs()
    assert reward(state, action).dtype == torch.float32
    assert reward(state.double(), action.double()).dtype == torch.float64
    other = CompoundReward(terms(), weights={"effort": 5.0})
    other.load_state_dict(reward.state_dict())
    assert torch.equal(other(state, action), reward(state, action))
    clone = copy.deepcopy(reward)
    clone.weights._buffers["effort"].fill_(3.0)
    assert reward.weights._buffers["effort"].item() == pytest.approx(0.1)


def test_stateful_terms_are_weighted_too() -> None:
    spec_terms = {"run": ForwardVelocityReward(dt=0.5, index=0), "alive": ConstantReward(1.0)}
    plain, weighted = CompoundReward(dict(spec_terms)), CompoundReward(dict(spec_terms), weights={"run": 0.25})
    start, after = torch.zeros(3, 2), torch.tensor([[1.0, 0.0], [2.0, 0.0], [-1.0, 0.0]])
    action = torch.zeros(3, 1)
    expected, _ = plain.step_terms(after, action, plain.reset(start))
    got, _ = weighted.step_terms(after, action, weighted.reset(start))
    torch.testing.assert_close(got["run"], 0.25 * expected["run"])
    torch.testing.assert_close(weighted.step(after, action, weighted.reset(start))[0], got["run"] + got["alive"])
    assert torch.count_nonzero(expected["run"]) == 3


@pytest.mark.parametrize(
    ("weights", "error", "match"),
    [
        ({"efort": 0.1}, ValueError, r"weights names unknown terms \['efort'\]; the terms are \['track', 'effort'"),
        ({"effort": math.nan}, ValueError, r"weights\['effort'\] must be finite"),
        ({"effort": math.inf}, ValueError, r"weights\['effort'\] must be finite"),
        ({"effort": True}, TypeError, r"weights\['effort'\] must be a real number"),
        ({"effort": "0.1"}, TypeError, r"weights\['effort'\] must be a real number"),
        ([0.1, 0.2, 0.3], TypeError, r"weights must be a mapping \{term name: weight\}.*got list"),
    ],
)
def test_bad_weights_are_refused_at_construction(weights, error, match) -> None:
    with pytest.raises(error, match=match):
        CompoundReward(terms(), weights=weights)


def test_sequence_terms_are_weighted_by_their_generated_names() -> None:
    reward = CompoundReward([ConstantReward(1.0), ConstantReward(2.0)], weights={"term1": 0.5})
    values = reward.terms(torch.zeros(2, 1), None)
    assert list(values) == ["term0", "term1"]
    assert values["term0"].tolist() == [1.0, 1.0] and values["term1"].tolist() == [1.0, 1.0]


def _pendulum_env(schedule_target: str) -> TransformedEnv:
    spec = EnvSpec(Box([-math.inf, -8.0], [math.inf, 8.0]), Box(-2.0, 2.0))
    reward = CompoundReward(
        {"track": QuadraticErrorReward([1.0, 0.1], None), "effort": QuadraticErrorReward([0.0, 0.0], [1e-3])},
        weights={"effort": 1.0},
    )
    task = FinalRewardTask(RadiallySymmetricDesiredStateTask(spec, [0.0, 0.0], reward, indices=[0], threshold=0.1))
    curriculum = Curriculum({schedule_target: staged({0: 0.0, 12: 2.0})})
    return TransformedEnv(PendulumEnv(batch_size=[4]), Compose(StepCounter(20), TaskTransform(task), curriculum))


def test_a_curriculum_schedules_a_weight_by_its_buffer_name_and_the_breakdown_follows() -> None:
    torch.manual_seed(0)
    env = _pendulum_env("wrapped_task.reward.weights.effort")
    data = env.rollout(6, break_when_any_done=False)
    # the entry at the root of a step is the value that step's reward was computed with
    weight = data["curriculum", "wrapped_task/reward/weights/effort"][..., 0]
    assert set(weight.unique().tolist()) == {0.0, 2.0}  # the staged weight switched during the rollout
    action = data["action"][..., 0].to(weight.dtype)
    effort = data["next", "task_reward", "effort"][..., 0]
    torch.testing.assert_close(effort, -1e-3 * action.square() * weight)
    assert bool((effort[weight == 2.0] != 0).all())


def test_a_misspelt_weight_target_lists_the_weight_names() -> None:
    with pytest.raises(ValueError, match=r"'wrapped_task\.reward\.weights\.effort'"):
        _pendulum_env("wrapped_task.reward.weights.efort").rollout(1)


def test_a_task_step_with_weighted_terms_compiles_to_one_graph() -> None:
    spec = EnvSpec(Box([-math.inf, -8.0], [math.inf, 8.0]), Box(-2.0, 2.0))
    reward = CompoundReward(terms(), weights={"effort": 0.1, "forward": -2.0})
    task = RadiallySymmetricDesiredStateTask(spec, [0.0, 0.0], reward, indices=[0], threshold=0.1)
    state, action = inputs()
    state, action, next_state = state.double(), action.double(), state.double() * 0.5
    memory = task.reset(state)

    def step(state, action, next_state, memory):
        out = task.transition(state, action, next_state, memory)
        return out.reward, out.terms["effort"], out.terms["forward"]

    torch._dynamo.reset()
    compiled = torch.compile(step, fullgraph=True, backend="aot_eager")
    eager = step(state, action, next_state, memory)
    for expected, got in zip(eager, compiled(state, action, next_state, memory), strict=True):
        assert torch.equal(expected, got)
    assert eager[2].tolist() == [-2.0] * 5
