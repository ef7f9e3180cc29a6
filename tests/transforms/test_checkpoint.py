"""BaseEnvState puts the base env's state into the transforms' state (issue 24, item 5), so TorchRL's own resume recipe
``collector.state_dict()`` -> ``torch.save`` -> a freshly built collector -> ``load_state_dict`` restores every
generator torchtasks owns: the base env's reset generator (PendulumEnv, PointMassEnv, BatchedMujocoEnv) and the
GoalCommand's, in a single-process Collector (the workers of a ParallelEnv inside a Collector and of a
MultiSyncCollector, each restored with its own seed: ``test_resume.py``, whose env ends in a BaseEnvState). The resumed
run equals an uninterrupted one on which ``collector.reset()`` is called at the same frame, bit for bit (deterministic
policy). The transform itself changes no data."""

from __future__ import annotations

import functools
import io

import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import Compose, EnvBase, SerialEnv, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, PointMassEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import BaseEnvState, GoalCommand, TaskTransform

BATCH = 3
STEPS = 10  # per batch and env; episodes of 7 steps: resets inside every batch
COMPARED = ["observation", ("next", "observation"), "action", "goal", ("next", "goal"), "goal_steps_left", "step_count"]


def base_env(kind: str, seed: int | None) -> EnvBase:
    if kind == "pendulum":
        return PendulumEnv(batch_size=[BATCH], seed=seed, dtype=torch.float64)
    if kind == "point_mass":
        return PointMassEnv(batch_size=[BATCH], seed=seed, dtype=torch.float64)
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    from torchtasks.envs import BatchedMujocoEnv

    return BatchedMujocoEnv("Hopper-v5", num_envs=BATCH, seed=seed, num_threads=1)


def make_env(
    kind: str = "pendulum", seed: int | None = None, *, state: bool = True, nested: bool = False
) -> TransformedEnv:
    """A task on the first two observation entries, judged against goals of a GoalCommand (module level: spawn-safe).

    ``state=False``: the same env without the BaseEnvState. ``nested``: that env (without a BaseEnvState) inside
    an outer TransformedEnv (``auto_unwrap=False``) whose only transform is the BaseEnvState.
    """
    env = base_env(kind, seed)
    spec = EnvSpec(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1])
    near = functools.partial(proximity_succeeded, threshold=0.05)
    reach = DesiredStateTask(spec.select_state([0, 1]), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), near)
    transforms = [
        StepCounter(7),
        TaskTransform(MaskedTask(spec, reach, [0, 1]), goal_key="goal"),
        GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), resample_steps=(2, 5)),
    ]
    if nested:
        inner = TransformedEnv(env, Compose(*transforms))
        return TransformedEnv(inner, Compose(BaseEnvState()), auto_unwrap=False)
    return TransformedEnv(env, Compose(*transforms, *([BaseEnvState()] if state else [])))


def make_collector(kind: str = "pendulum", *, state: bool = True, nested: bool = False) -> Collector:
    """A freshly built collector (other generators each time) with a deterministic policy (saved in its state)."""
    env = make_env(kind, state=state, nested=nested)
    sizes = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    policy = TensorDictModule(
        torch.nn.Sequential(torch.nn.Linear(*sizes, dtype=torch.float64), torch.nn.Tanh()), ["observation"], ["action"]
    )
    frames = env.batch_size.numel() * STEPS
    return Collector(env, policy, frames_per_batch=frames, total_frames=-1, auto_register_policy_transforms=False)


def saved_and_loaded(state: dict) -> dict:
    """``torch.save`` then ``torch.load`` (``weights_only``): what a new process reads."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer)


def resume_check(kind: str, *, nested: bool = False) -> dict:
    """Run 3 batches, save, load into a fresh collector, reset both, compare the next 2 batches; the saved state."""
    running = make_collector(kind, nested=nested)
    try:
        running.set_seed(5)
        running.reset()
        batches = iter(running)
        for _ in range(3):
            next(batches)
        saved = saved_and_loaded(running.state_dict())
        fresh = make_collector(kind, nested=nested)
        try:
            fresh.load_state_dict(saved)
            for collector in (running, fresh):
                collector.reset()  # a loaded collector starts fresh trajectories: start them in both
            fresh_batches = iter(fresh)
            for _ in range(2):
                expected, resumed = next(batches), next(fresh_batches)
                for key in COMPARED:
                    assert torch.equal(expected[key], resumed[key]), key
        finally:
            fresh.shutdown()
    finally:
        running.shutdown()
    return saved


@pytest.mark.parametrize("kind", ["pendulum", "point_mass", "mujoco"])
def test_a_collector_checkpoint_restores_the_base_env_and_the_command(kind: str):
    saved = resume_check(kind)
    assert "transforms.3._extra_state" in saved["env_state_dict"]  # the base env's state, in the transforms'
    assert "transforms.2._extra_state" in saved["env_state_dict"]  # the command's generator


def test_in_the_outer_env_of_a_nested_env_it_saves_every_env_below_it():
    """TorchRL's Collector.state_dict() saves the outermost env's transforms only: a BaseEnvState there saves the
    inner TransformedEnv's transforms (the task's command) and, the inner env holding none, the innermost base env."""
    saved = resume_check("pendulum", nested=True)
    (key,) = saved["env_state_dict"].keys()
    inner = saved["env_state_dict"][key]
    assert "transforms.2._extra_state" in inner  # the command's generator, in the inner env's transforms
    assert "_inner_base_env" in inner  # the pendulum's reset generator


def test_without_it_the_base_env_is_not_restored():
    """The control: the same recipe without BaseEnvState restores the goals but not the base env's reset draws."""
    running = make_collector(state=False)
    running.set_seed(5)
    running.reset()
    next(iter(running))
    fresh = make_collector(state=False)
    fresh.load_state_dict(saved_and_loaded(running.state_dict()))
    for collector in (running, fresh):
        collector.reset()
    expected, resumed = next(iter(running)), next(iter(fresh))
    assert torch.equal(expected["goal"], resumed["goal"])
    assert not torch.equal(expected["observation"][:, 0], resumed["observation"][:, 0])
    running.shutdown()
    fresh.shutdown()


def test_it_changes_no_data_and_carries_a_batched_base_env():
    a, b = make_env(seed=1), make_env(seed=1, state=False)
    policy = make_collector().policy  # deterministic (env.rollout's default draws random actions)
    for env in (a, b):
        env.set_seed(2)
    data_a, data_b = (env.rollout(9, policy, break_when_any_done=False) for env in (a, b))
    assert set(data_a.keys(True, True)) == set(data_b.keys(True, True))
    for key in ("observation", ("next", "observation"), "goal", ("next", "reward")):
        assert torch.equal(data_a[key], data_b[key]), key
    assert a.observation_spec == b.observation_spec and a.state_spec == b.state_spec
    # a SerialEnv base: one state per worker, restored into a fresh one
    factory = functools.partial(PendulumEnv, batch_size=[2], dtype=torch.float64)
    serial = TransformedEnv(SerialEnv(2, factory), Compose(StepCounter(5), BaseEnvState()))
    serial.set_seed(3)
    state = saved_and_loaded(serial.state_dict())
    assert {key for key in state["transforms.1._extra_state"] if key.startswith("worker")} == {"worker0", "worker1"}
    fresh = TransformedEnv(SerialEnv(2, factory), Compose(StepCounter(5), BaseEnvState()))
    fresh.load_state_dict(state)
    assert torch.equal(serial.reset()["observation"], fresh.reset()["observation"])


def test_outside_an_env_and_wrong_states_are_refused():
    with pytest.raises(
        ValueError, match="BaseEnvState cannot save the base env's state: it is not in a TransformedEnv"
    ):
        BaseEnvState().state_dict()
    with pytest.raises(ValueError, match="cannot load the base env's state: it is not in a TransformedEnv"):
        Compose(BaseEnvState()).load_state_dict({"transforms.0._extra_state": {}})
    env = make_env()
    with pytest.raises(TypeError, match="must be the base env's state_dict \\(a mapping\\), got int"):
        env.transform[-1].load_state_dict({"_extra_state": 3})
    with pytest.raises(ValueError, match="uint8 tensor 'generator_state'"):  # the base env's own check
        env.transform[-1].load_state_dict({"_extra_state": {"_extra_state": {"seed": 0}}})
