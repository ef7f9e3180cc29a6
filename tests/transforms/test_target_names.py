"""What an env's writers can set, and the short names users type (issue 35, item 1).

:func:`~torchtasks.transforms.target_names` lists the targets of an env that has no writer yet; the expected
names are computed here from ``task.named_buffers()`` (float dtypes), the base env's float buffers and the
parameters written by hand. Every listed alias, and every full name, is accepted by a Curriculum (and by
DifficultyLevels where the table says so) and resolves to the buffer of its full name; a short name that ends
several names is refused naming them; a forward weight scheduled by its short name on Hopper pays the reward a
hand computation gives; data and checkpoints keyed by a short name are read back (offline recomputation, a
resumed Curriculum) and a load under the other spelling is refused.
"""

from __future__ import annotations

import copy
import functools
import math

import pytest
import torch
from torch import nn
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv
from torchtasks.rewards import CompoundReward, QuadraticErrorReward, RewardFunction
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, proximity_succeeded
from torchtasks.transforms import (
    Curriculum,
    DifficultyLevels,
    GoalCommand,
    TaskTransform,
    constant,
    linear,
    target_names,
)
from walk_env import WalkEnv, walk_task

FLOATS = (torch.float16, torch.bfloat16, torch.float32, torch.float64)


def _task(env: TransformedEnv) -> nn.Module:
    (task_transform,) = [t for t in env.transform if isinstance(t, TaskTransform)]
    return task_transform.task


def _float_buffers(module: nn.Module) -> dict[str, torch.Tensor]:
    return {name: buffer for name, buffer in module.named_buffers() if buffer.dtype in FLOATS}


def _schedule_every_alias(env: TransformedEnv, table) -> Curriculum:
    """A Curriculum holding every Curriculum row of ``table`` by its alias, each at its value of now."""
    rows = [row for row in table if "Curriculum" in row.writers]
    task = _task(env)
    schedules = {row.alias: constant(_float_buffers(task)[row.name].clone()) for row in rows}
    curriculum = Curriculum(schedules)
    env.append_transform(curriculum)
    return curriculum


# ----------------------------------------------------------------------------------------------------- presets
PRESETS = {
    "gymnasium_env": ("gymnasium_env", "Hopper-v5"),
    "safety_velocity_env": ("safety_velocity_env", "Hopper-v5"),
    "multi_objective_env": ("multi_objective_env", "mo-hopper-v5"),
}
BACKENDS = {"batched": {"num_envs": 2, "backend": "batched"}, "gymnasium": {"num_envs": 1, "backend": "gymnasium"}}


def _preset(family: str, backend: str) -> TransformedEnv:
    import torchtasks.envs

    name, env_id = PRESETS[family]
    return getattr(torchtasks.envs, name)(env_id, seed=0, **BACKENDS[backend])


@pytest.mark.mujoco
@pytest.mark.parametrize("backend", list(BACKENDS))
@pytest.mark.parametrize("family", list(PRESETS))
def test_a_preset_lists_the_names_the_resolver_accepts_and_every_alias_is_schedulable(family, backend):
    env = _preset(family, backend)
    try:
        table = target_names(env)
        task = _task(env)
        expected = sorted(_float_buffers(task)) + sorted(f"env.{n}" for n in _float_buffers(env.base_env))
        assert sorted(table.names) == sorted(expected)
        assert len(set(table.aliases)) == len(table.aliases)
        # each alias is the shortest dotted suffix of >= 2 parts that ends its own name only
        for row in table:
            parts = row.name.split(".")
            assert row.name == row.alias or row.name.endswith("." + row.alias)
            others = [n for n in table.names if n != row.name]
            if row.alias != row.name:  # a full name means itself, even if it ends another name (state_low)
                assert not any(n == row.alias or n.endswith("." + row.alias) for n in others)
            shorter = [".".join(parts[-k:]) for k in range(2, len(row.alias.split(".")))]
            assert all(any(n == s or n.endswith("." + s) for n in others) for s in shorter)
        aliases = dict(zip(table.names, table.aliases, strict=True))
        inner = "wrapped_task." if family != "gymnasium_env" else ""
        assert aliases[f"{inner}reward.rewards.forward.weight"] == "forward.weight"
        assert aliases[f"{inner}reward.rewards.ctrl.weight"] == "ctrl.weight"
        assert aliases[f"{inner}reward.rewards.survive.healthy_reward"] == "survive.healthy_reward"
        # every alias is accepted and resolves to the buffer of its full name; one short rollout writes them all
        curriculum = _schedule_every_alias(env, table)
        buffers = _float_buffers(task)
        for target in curriculum.written_targets():
            assert target.value is buffers[target.path] and aliases[target.path] == target.name
        data = env.rollout(2, break_when_any_done=False)
        for row in table:
            recorded = data["curriculum", row.alias.replace(".", "/")]
            assert torch.equal(recorded[..., -1, :], buffers[row.name].expand_as(recorded[..., -1, :]).to(recorded))
    finally:
        env.close()


@pytest.mark.mujoco
def test_forward_weight_scheduled_by_its_short_name_on_hopper_pays_the_hand_computed_reward():
    from torchtasks.envs import gymnasium_env

    env = gymnasium_env("Hopper-v5", num_envs=2, seed=0, backend="batched")
    env.append_transform(Curriculum({"forward.weight": linear(0.0, 2.0, 0, 8)}))
    torch.manual_seed(0)
    data = env.rollout(6, break_when_any_done=False)
    env.close()
    # the frame count before step t is 2 t (2 envs): the weight step t pays with is 2 * min(1, 2 t / 8)
    weights = torch.tensor([2.0 * min(1.0, 2 * t / 8) for t in range(6)], dtype=torch.float64)
    assert torch.equal(data["curriculum", "forward/weight"][0, :, 0], weights)
    nxt = data["next"]
    forward = weights.view(1, 6, 1) * nxt["x_velocity"].reshape(2, 6, 1)
    assert torch.allclose(nxt["task_reward", "forward"], forward.to(nxt["task_reward", "forward"]))
    action = data["action"].to(torch.float64)
    healthy = (~nxt["failure"]).to(torch.float64)  # Hopper pays 1 per healthy step (terminate_when_unhealthy)
    hand = forward + healthy - 1e-3 * (action * action).sum(-1, keepdim=True)
    assert torch.allclose(nxt["reward"].to(torch.float64), hand, atol=1e-6)
    assert not torch.allclose(nxt["task_reward", "forward"], nxt["x_velocity"].reshape(2, 6, 1).to(forward))


# ------------------------------------------------------------------------------------------ commands and domain
def _walk_env(batch: int = 4) -> TransformedEnv:
    command = GoalCommand(Box([-1.0], [1.0]), seed=0)
    return TransformedEnv(
        WalkEnv([batch]), Compose(StepCounter(5), TaskTransform(walk_task(), goal_key="goal"), command)
    )


COMMAND_RANGE = ["command.goal.low", "command.goal.high"]


def test_an_env_with_a_goal_command_lists_its_range_env_fields_and_which_writer_takes_them():
    env = _walk_env()
    table = target_names(env)
    rows = {row.name: row for row in table}
    # walk_task(): a DesiredStateTask around a QuadraticErrorReward; WalkEnv's per-env step size; the range
    assert sorted(rows) == sorted(
        ["reward.Q", "reward.R", "state_des", "state_high", "state_low", "env.step_size", *COMMAND_RANGE]
    )
    assert rows["command.goal.low"].alias == "command.low" and rows["command.goal.high"].alias == "command.high"
    assert rows["env.step_size"].writers == ("DifficultyLevels",) and rows["env.step_size"].shape == (4,)
    assert rows["reward.Q"].writers == ("Curriculum",)
    assert rows["command.goal.low"].writers == ("Curriculum", "DifficultyLevels")
    assert rows["reward.Q"].source == "task" and rows["env.step_size"].source == "env"
    lines = str(table).splitlines()
    assert len(lines) == 1 + len(table) and lines[0].split() == ["alias", "name", "source", "shape", "writers", "value"]
    assert any(line.split()[:3] == ["command.low", "command.goal.low", "command"] for line in lines)
    # the levels accept every row that names them, by alias, inserted before the GoalCommand (as the docstring says)
    tables = {"env.step_size": [0.4, 0.2], "command.low": [[-0.5], [-1.0]], "command.high": [[0.5], [1.0]]}
    assert sorted(tables) == sorted(row.alias for row in table if "DifficultyLevels" in row.writers)
    levels = DifficultyLevels(2, tables)
    env.insert_transform(2, levels)
    targets = {target.name: target for target in levels.written_targets()}
    assert targets["command.low"].module is env.transform[3] and targets["command.low"].buffer == "low"
    assert targets["env.step_size"].module is env.base_env and targets["env.step_size"].buffer == "step_size"


def test_a_preset_with_a_domain_randomization_lists_its_distribution_parameters():
    pytest.importorskip("mujoco")
    from torchtasks.domain import UniformDomainParam
    from torchtasks.envs import gymnasium_env
    from torchtasks.transforms import DomainRandomization

    env = gymnasium_env("Hopper-v5", num_envs=2, seed=0, backend="batched")
    env.append_transform(DomainRandomization([UniformDomainParam("body_mass_scale", mean=1.0, halfspan=0.1)], seed=0))
    table = target_names(env)
    domain = [row for row in table if row.source == "domain"]
    parameters = ["mean", "halfspan", "clip_lo", "clip_up"]  # a UniformDomainParam's buffers (docs table)
    assert sorted(row.name for row in domain) == sorted(f"domain.body_mass_scale.{p}" for p in parameters)
    assert all(row.alias == row.name for row in domain)
    env.append_transform(
        Curriculum({"domain.body_mass_scale.halfspan": linear(0.0, 0.2, 0, 8), "ctrl.weight": constant(0.002)})
    )
    data = env.rollout(2, break_when_any_done=False)
    assert data["curriculum", "ctrl/weight"][0, :, 0].tolist() == [0.002, 0.002]
    env.close()


# ------------------------------------------------------------------------------------------------- ambiguity
def _two_weights_task() -> FinalRewardTask:
    """Two terms whose weight buffers end alike: ``track.Q`` and ``effort.Q``, ``rewards.*`` and ``weights.*``."""
    spec = EnvSpec(Box([-3 * math.pi, -8.0], [3 * math.pi, 8.0]), Box([-2.0], [2.0]))
    reward = CompoundReward(
        {"track": QuadraticErrorReward([1.0, 0.1], None), "effort": QuadraticErrorReward([0.0, 0.0], [0.01])},
        weights={"effort": 1.0},
    )
    near = functools.partial(proximity_succeeded, threshold=0.5)
    return FinalRewardTask(DesiredStateTask(spec, [math.pi, 0.0], reward, near), factor=10.0)


def _pendulum(*transforms) -> TransformedEnv:
    return TransformedEnv(
        PendulumEnv([4], seed=0), Compose(StepCounter(20), TaskTransform(_two_weights_task()), *transforms, RewardSum())
    )


@pytest.mark.parametrize("kind", ["Curriculum", "DifficultyLevels"])
@pytest.mark.parametrize(
    ("short", "candidates"),
    [
        ("Q", ["wrapped_task.reward.rewards.track.Q", "wrapped_task.reward.rewards.effort.Q"]),
        ("state_low", None),  # a full name (of the root), though it also ends wrapped_task.state_low: accepted
    ],
)
def test_a_short_name_that_ends_several_names_is_refused_naming_them(kind, short, candidates):
    writer = Curriculum({short: constant(1.0)}) if kind == "Curriculum" else DifficultyLevels(2, {short: [1.0, 1.0]})
    env = _pendulum(writer)
    if candidates is None:
        if kind == "Curriculum":
            (target,) = writer.written_targets()
            assert target.value is _task(env)._buffers["state_low"]
        return
    with pytest.raises(ValueError) as error:
        env.reset()
    assert str(error.value) == (
        f"{kind}: the target 'Q' is ambiguous: it ends 2 buffer names of the task tree, {candidates}; did you mean "
        "'track.Q' or 'effort.Q'? (a short name must end one name only)"
    )


def test_a_short_name_and_the_full_name_of_one_buffer_are_refused_together():
    env = _pendulum(Curriculum({"track.Q": constant(1.0), "wrapped_task.reward.rewards.track.Q": constant(2.0)}))
    with pytest.raises(ValueError, match=r"'track.Q' and 'wrapped_task.reward.rewards.track.Q' name the same target"):
        env.reset()


def test_a_misspelt_short_name_gets_a_did_you_mean_for_it():
    env = _pendulum(Curriculum({"weigths.effort": constant(1.0)}))
    with pytest.raises(ValueError, match=r"unknown target 'weigths.effort'; did you mean 'weights.effort'\?"):
        env.reset()


# ------------------------------------------------------------------------------- data and checkpoints by alias
def test_offline_recomputation_reads_values_recorded_under_a_short_name():
    schedules = {"weights.effort": linear(0.0, 8.0, 0, 80), "track.Q": linear([1.0, 0.1], [0.25, 1.0], 0, 80)}
    env = _pendulum(Curriculum(schedules))
    torch.manual_seed(0)
    with torch.no_grad():
        data = env.rollout(20, break_when_any_done=False)
    assert set(data["curriculum"].keys()) == {"frames", "weights/effort", "track/Q"}
    paid = data["next", "reward"].clone()
    for transform in (env.transform[1], TaskTransform(_two_weights_task(), max_steps=20)):  # in the env, and outside
        stripped = data.clone()
        stripped["next", "reward"].zero_()
        assert torch.allclose(transform(stripped)["next", "reward"], paid)
    # the buffers of today (the ramps' ends) pay other rewards: the recorded values were read
    today = data.clone()
    today["curriculum", "weights/effort"].fill_(8.0)
    today["curriculum", "track/Q"].copy_(torch.tensor([0.25, 1.0]).expand_as(today["curriculum", "track/Q"]))
    assert not torch.allclose(TaskTransform(_two_weights_task(), max_steps=20)(today)["next", "reward"], paid)


class PerEnvWeight(RewardFunction):
    """``-weight · |e|²`` with one ``weight`` per env (``[B]``), a buffer the levels set."""

    uses_action = False

    def __init__(self, envs: int) -> None:
        super().__init__()
        self.register_buffer("weight", torch.ones(envs, dtype=torch.float64))

    def forward(self, error_state: torch.Tensor, error_action: torch.Tensor | None = None) -> torch.Tensor:
        return self._value(error_state, error_action)

    def _value(self, error_state: torch.Tensor, error_action: torch.Tensor | None) -> torch.Tensor:
        return -self.weight.to(error_state.dtype) * (error_state * error_state).sum(-1)


def _levelled_task() -> FinalRewardTask:
    spec = EnvSpec(Box([-3 * math.pi, -8.0], [3 * math.pi, 8.0]), Box([-2.0], [2.0]))
    near = functools.partial(proximity_succeeded, threshold=0.5)
    return FinalRewardTask(DesiredStateTask(spec, [math.pi, 0.0], PerEnvWeight(4), near), factor=10.0)


def _up_at_every_end(tensordict, next_tensordict) -> torch.Tensor:
    return torch.ones(next_tensordict.batch_size, dtype=torch.int64)


def test_levels_by_a_short_name_record_rows_that_offline_recomputation_reads():
    levels = DifficultyLevels(3, {"reward.weight": [1.0, 2.0, 4.0]}, rule=_up_at_every_end)
    env = TransformedEnv(PendulumEnv([4], seed=0), Compose(StepCounter(5), TaskTransform(_levelled_task()), levels))
    assert {row.alias: row.writers for row in target_names(env)}["reward.weight"] == ("Curriculum", "DifficultyLevels")
    torch.manual_seed(0)
    with torch.no_grad():
        data = env.rollout(12, break_when_any_done=False)
    recorded = data["curriculum", "reward/weight"]
    assert recorded.shape == (4, 12) and set(recorded.unique().tolist()) == {1.0, 2.0, 4.0}
    paid = data["next", "reward"].clone()
    for transform in (env.transform[1], TaskTransform(_levelled_task(), max_steps=5)):  # in the env, and outside
        stripped = data.clone()
        stripped["next", "reward"].zero_()
        assert torch.allclose(transform(stripped)["next", "reward"], paid)
    today = data.clone()
    today["curriculum", "reward/weight"].fill_(4.0)
    assert not torch.allclose(TaskTransform(_levelled_task(), max_steps=5)(today)["next", "reward"], paid)
    with pytest.raises(ValueError, match="unknown target 'step_size'"):  # an env field is named in full ("env.")
        TransformedEnv(
            WalkEnv([4]),
            Compose(StepCounter(5), TaskTransform(walk_task()), DifficultyLevels(2, {"step_size": [0.4, 0.2]})),
        ).reset()


def test_a_curriculum_checkpoint_under_a_short_name_continues_and_refuses_the_other_spelling():
    def make(name: str) -> tuple[TransformedEnv, Curriculum]:
        curriculum = Curriculum({name: linear(0.0, 8.0, 0, 40)})
        return _pendulum(curriculum), curriculum

    whole, _ = make("weights.effort")
    uninterrupted = whole.rollout(8, break_when_any_done=False)["curriculum", "weights/effort"][0, 4:, 0]
    first, curriculum = make("weights.effort")
    first.rollout(4, break_when_any_done=False)
    saved = copy.deepcopy(curriculum.state_dict())
    resumed, again = make("weights.effort")
    again.load_state_dict(saved)
    continued = resumed.rollout(4, break_when_any_done=False)["curriculum", "weights/effort"][0, :, 0]
    # the reset of the new rollout writes the loaded count's value: 16 frames -> 3.2, then +0.8 per step
    assert continued.tolist() == pytest.approx([3.2, 4.0, 4.8, 5.6]) and torch.equal(continued, uninterrupted)
    _, full = make("wrapped_task.reward.weights.effort")
    with pytest.raises(ValueError) as error:
        full.load_state_dict(saved)
    assert "here may be 'weights/effort' of the checkpoint spelt another way" in str(error.value)
