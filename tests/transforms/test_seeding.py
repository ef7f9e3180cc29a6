"""env.set_seed seeds the generators of torchtasks transforms (issue 24, item 5): after ``set_seed(s)`` on a
``SerialEnv``/``ParallelEnv`` of TransformedEnvs, a ``Collector`` or a ``MultiSyncCollector``, every worker's
GoalCommand draws its own stream, the same ``s`` gives the same goals, another ``s`` others; two GoalCommands of one
env differ; each seeded transform is seeded once per call; copies and pickles of the env keep seeding their own
transforms; the next seed returned is TorchRL's."""

from __future__ import annotations

import copy
import functools
import pickle

import pytest
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.envs import Compose, EnvBase, ParallelEnv, SerialEnv, StepCounter, TransformedEnv

from torchtasks.envs import PointMassEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, FinalRewardTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import GoalCommand, SeededTransform, SeedHook, TaskTransform, derived_seed, seed_transforms

GOALS = Box([-0.8, -0.8], [0.8, 0.8])
BATCH = 3
STEPS = 12


def reach_task() -> FinalRewardTask:
    """Reach the goal position (x, y) of a point mass within 0.1."""
    spec = EnvSpec(Box([-1.0] * 4, [1.0] * 4, labels=list(PointMassEnv.labels)), 2)
    near = functools.partial(proximity_succeeded, threshold=0.1)
    reach = DesiredStateTask(spec.select_state(["x", "y"]), [0.0, 0.0], QuadraticErrorReward([1.0, 1.0]), near)
    return FinalRewardTask(MaskedTask(spec, reach, ["x", "y"]), factor=1.0)


def make_env(command_seed: int | None = 0) -> TransformedEnv:
    """A point mass reaching goals of a GoalCommand built with ``seed=command_seed`` (spawn-safe: module level)."""
    return TransformedEnv(
        PointMassEnv(batch_size=[BATCH]),
        Compose(
            StepCounter(8),
            TaskTransform(reach_task(), goal_key="goal"),
            GoalCommand(GOALS, resample_steps=(2, 4), seed=command_seed),
        ),
    )


def zero_force(observation: torch.Tensor) -> torch.Tensor:
    return torch.zeros((*observation.shape[:-1], 2), dtype=observation.dtype)


#: a deterministic policy (``env.rollout``'s default draws random actions from torch's global generator)
zero_actions = TensorDictModule(zero_force, ["observation"], ["action"])


def goals_of(env: EnvBase, seed: int | None) -> TensorDictBase:
    """Seed ``env`` (unless ``seed`` is None), roll it out with zero actions (resets and timers draw goals)."""
    if seed is not None:
        env.set_seed(seed)
    data = env.rollout(STEPS, zero_actions, break_when_any_done=False)
    return data.select("goal", ("next", "goal"), "observation", "goal_steps_left")


def assert_equal(a: TensorDictBase, b: TensorDictBase) -> None:
    for key in a.keys(True, True):
        assert torch.equal(a[key], b[key]), key


def assert_workers_differ(data: TensorDictBase) -> None:
    """Worker 0's goals differ from worker 1's everywhere (continuous draws: equal only if the streams are equal)."""
    assert (data[0]["goal"] != data[1]["goal"]).all()
    assert (data[0]["next", "goal"] != data[1]["next", "goal"]).all()


# ----------------------------------------------------------------------------------------- batched envs
@pytest.mark.parametrize("command_seed", [0, None], ids=["seed=0", "seed=None"])
def test_serial_env_workers_draw_their_own_goals_and_a_seed_repeats_the_run(command_seed):
    data = goals_of(SerialEnv(2, functools.partial(make_env, command_seed)), 123)
    assert_workers_differ(data)
    assert_equal(goals_of(SerialEnv(2, functools.partial(make_env, command_seed)), 123), data)
    other = goals_of(SerialEnv(2, functools.partial(make_env, command_seed)), 124)
    assert (other["goal"] != data["goal"]).all()
    assert (other["observation"] != data["observation"]).any()  # the base envs are seeded too, as TorchRL does


@pytest.mark.multiprocess
def test_parallel_env_workers_draw_their_own_goals():
    """Workers built by the factory in their own processes are seeded as SerialEnv's (the same goals, bit for bit).

    Forked, as the other worker-process tests: a spawned worker rebuilding env, task and transform from the pickled
    constructor is ``test_transform_collectors.py::test_parallel_env_spawn`` (spawning two workers cost ~15 s).
    """
    parallel = ParallelEnv(2, functools.partial(make_env, 0), mp_start_method="fork")
    try:
        data = goals_of(parallel, 123)
    finally:
        parallel.close()
    assert_workers_differ(data)
    assert_equal(goals_of(SerialEnv(2, functools.partial(make_env, 0)), 123), data)


def test_the_next_seed_is_torchrl_s():
    plain = SerialEnv(2, lambda: TransformedEnv(PointMassEnv(batch_size=[BATCH]), StepCounter(8)))
    assert SerialEnv(2, make_env).set_seed(5) == plain.set_seed(5)
    assert make_env().set_seed(5) == PointMassEnv(batch_size=[BATCH]).set_seed(5)
    assert make_env().set_seed(5, static_seed=True) == 5


# ------------------------------------------------------------------------------------------- collectors
def test_collector_set_seed_seeds_the_commands():
    def first_batch(seed: int) -> TensorDictBase:
        collector = Collector(
            make_env(),
            zero_actions,
            frames_per_batch=BATCH * STEPS,
            total_frames=-1,
            auto_register_policy_transforms=False,
        )
        collector.set_seed(seed)
        collector.reset()  # a Collector resets its env when built, before the seed: start new trajectories
        batch = next(iter(collector)).select("goal", ("next", "goal"), "observation").clone()
        collector.shutdown()
        return batch

    batch = first_batch(3)
    assert_equal(first_batch(3), batch)
    assert (first_batch(4)["goal"] != batch["goal"]).all()
    # what env.set_seed(3) and a rollout give; not what the command's own seed=0 gives
    assert_equal(batch, goals_of(make_env(), 3).select(*batch.keys(True, True)))
    assert (goals_of(make_env(), None)["goal"] != batch["goal"]).all()


@pytest.mark.multiprocess
def test_multi_sync_collector_set_seed_seeds_each_worker(fork_start_method):
    """Goals do not depend on the actions (no resampling on success): the random policy of policy=None is fine."""
    collector = MultiSyncCollector(
        [make_env, make_env], None, frames_per_batch=2 * BATCH * STEPS, total_frames=-1, cat_results="stack"
    )
    try:
        collector.set_seed(11)
        batch = next(iter(collector))
    finally:
        collector.shutdown()
    assert batch.shape == (2, BATCH, STEPS)  # the workers' batches, stacked
    assert_workers_differ(batch)
    # worker 0 got seed 11 and worker 1 TorchRL's next seed: as the workers of a SerialEnv of the same envs
    expected = goals_of(SerialEnv(2, make_env), 11)
    assert torch.equal(batch["goal"], expected["goal"])
    assert torch.equal(batch["next", "goal"], expected["next", "goal"])


# --------------------------------------------------------------------------------------------- one env
def test_two_commands_of_one_env_draw_different_streams_and_not_the_base_env_s():
    commands = [GoalCommand(GOALS, goal_key=key, resample_steps=(2, 4), seed=0) for key in ("goal", "goal2")]
    env = TransformedEnv(PointMassEnv(batch_size=[BATCH]), Compose(StepCounter(8), *commands))
    data = env.rollout(STEPS, zero_actions, break_when_any_done=False)
    assert torch.equal(data["goal"], data["goal2"])  # the premise: both built with seed=0 draw alike
    env.set_seed(123)
    data = env.rollout(STEPS, zero_actions, break_when_any_done=False)
    assert (data["goal"] != data["goal2"]).all()
    seeds = [command.generator.initial_seed() for command in commands]
    assert seeds == [derived_seed(123, 0, "GoalCommand('goal')"), derived_seed(123, 1, "GoalCommand('goal2')")]
    assert 123 not in seeds and env.base_env.rng.initial_seed() == 123


def test_a_command_on_the_global_generator_gets_its_own_at_set_seed_only():
    env = make_env(None)
    command = env.transform[-1]
    assert command.generator is None  # torch's global generator until the env is seeded
    env.set_seed(None)  # no seed: the base env draws fresh entropy (TorchRL), the command is left as it is
    assert command.generator is None
    env.set_seed(1)
    assert command.generator is not None
    state = command.state_dict()["_extra_state"]
    assert state["own_generator"] and state["seed"] == derived_seed(1, 0, "GoalCommand('goal')")


class CountingSeeds(SeededTransform):
    """A seeded transform that records the seeds it gets."""

    def __init__(self) -> None:
        super().__init__()
        self.seeds: list[int] = []

    def set_seed(self, seed: int) -> None:
        self.seeds.append(seed)


def test_every_seeded_transform_is_seeded_once_per_call_also_in_nested_envs_and_appended():
    inner_counter, outer_counter, appended = CountingSeeds(), CountingSeeds(), CountingSeeds()
    inner = TransformedEnv(PointMassEnv(batch_size=[BATCH]), Compose(StepCounter(8), Compose(inner_counter)))
    env = TransformedEnv(inner, outer_counter, auto_unwrap=False)
    env.append_transform(appended)
    for hooked in (env, inner):
        assert isinstance(hooked.__dict__["set_seed"], SeedHook)
    env.set_seed(7)
    counters = [inner_counter, outer_counter, appended]
    assert [len(c.seeds) for c in counters] == [1, 1, 1]
    assert len({c.seeds[0] for c in counters}) == 3  # indexed across the nested envs: three streams
    assert inner_counter.seeds[0] == derived_seed(7, 0, "CountingSeeds")
    seed_transforms(env, 7)  # the transform part alone, the same seeds
    assert [c.seeds for c in counters] == [[s, s] for s in (c.seeds[0] for c in counters)]


def test_seed_transforms_checks_its_arguments():
    with pytest.raises(TypeError, match="env must be a torchrl TransformedEnv, got PointMassEnv"):
        seed_transforms(PointMassEnv(batch_size=[2]), 0)
    with pytest.raises(TypeError, match=r"seed_transforms: seed must be an int, got 1\.5"):
        seed_transforms(make_env(), 1.5)
    with pytest.raises(TypeError, match=r"env.set_seed: seed must be an int, got '1'"):
        make_env().set_seed("1")


def test_copies_and_pickles_seed_their_own_commands():
    env = make_env(None)
    env.set_seed(2)
    copies = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    for other in copies:
        assert other.set_seed.env is other
        state = env.transform[-1].generator.get_state()
        assert_equal(goals_of(other, 9), goals_of(make_env(None), 9))
        assert torch.equal(env.transform[-1].generator.get_state(), state)  # the original is left alone
    assert_equal(goals_of(env, 9), goals_of(copies[0], 9))


def test_a_gym_env_base_is_seeded_with_its_commands():
    gym_env = pytest.importorskip("torchrl.envs.libs.gym").GymEnv
    pytest.importorskip("gymnasium")

    def run(seed: int) -> TensorDictBase:
        env = TransformedEnv(gym_env("Pendulum-v1"), Compose(StepCounter(5), GoalCommand(GOALS, resample_steps=2)))
        return goals_of(env, seed)

    data = run(4)
    assert_equal(run(4), data)
    assert (run(5)["goal"] != data["goal"]).all()
