"""Resumes continue the saved run (issue 30): the batches after a resume equal the uninterrupted run's, entry by entry.

The recipe: ``collector_state(collector)`` -> ``torch.save`` -> a freshly built collector in the same process ->
``load_collector_state(collector, torch.load(...))``, with no ``collector.reset()`` in either run. The episodes in
progress at the checkpoint go on: the observation, ``step_count``, ``RewardSum``'s running sums, the task memory, the
``GoalCommand``'s goals and timers, the curriculum entries and ``("collector", "traj_ids")`` of the first frame after
the resume are those the saved run carried, and every later batch equals the uninterrupted run's bit for bit
(deterministic policy). Checked for a ``Collector`` over the resume env (``PointMassEnv``) and a pendulum variant, a
``ParallelEnv`` inside a ``Collector``, a ``MultiSyncCollector`` and ``BatchedMujocoEnv`` presets (whose physics,
with the solver's warm start, is in the checkpoint). Loads that cannot continue are refused with errors naming both
sides; TorchRL's own load without a reset warns once.
"""

from __future__ import annotations

import functools
import io
import warnings
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.envs import Compose, ParallelEnv, RewardSum, StepCounter, TransformedEnv

from resume_env import equal_batches, make_parallel_resume_env, make_resume_env, reach_policy
from torchtasks.domain import NormalDomainParam, UniformDomainParam
from torchtasks.envs import PendulumEnv, PointMassEnv
from torchtasks.rewards import QuadraticErrorReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.tasks import DesiredStateTask, MaskedTask, proximity_succeeded
from torchtasks.transforms import (
    BaseEnvState,
    Curriculum,
    DifficultyLevels,
    DomainRandomization,
    GoalCommand,
    TaskTransform,
    collector_state,
    gated,
    linear,
    load_collector_state,
)

SEED = 7
BEFORE = 3  # batches collected before the checkpoint
AFTER = 2  # batches compared after it
STALE = "stepped after load_state_dict without a reset"  # BaseEnvState's warning


# ------------------------------------------------------------------------------ envs and collectors
def make_pendulum_resume_env(batch: int = 4) -> TransformedEnv:
    """The resume env's transforms on a PendulumEnv: a goal angle and speed, scheduled weights, levels, timers."""
    spec = EnvSpec(Box([-100.0, -8.0], [100.0, 8.0], labels=["theta", "speed"]), 1)
    near = functools.partial(proximity_succeeded, threshold=0.2)
    task = MaskedTask(spec, DesiredStateTask(spec, [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.0]), near), [0, 1])
    curriculum = Curriculum(
        {
            "wrapped_task.reward.R": linear(0.0, 0.01, 0, 600),
            "wrapped_task.reward.Q": gated([1.0, 2.0], metric="success", threshold=0.3, window=4),
        }
    )
    half_widths = torch.tensor([0.2, 0.5]).unsqueeze(-1).expand(2, 2)
    levels = DifficultyLevels(2, {"command.low": -half_widths, "command.high": half_widths})
    return TransformedEnv(
        PendulumEnv(batch_size=[batch], init_angle=0.5),
        Compose(
            StepCounter(25),
            TaskTransform(task, goal_key="goal"),
            RewardSum(),
            curriculum,
            levels,
            GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), resample_steps=(6, 12)),
            BaseEnvState(),
        ),
    )


class PendulumPD(torch.nn.Module):
    """``u = 8 (goal_angle - θ) + 1.5 (goal_speed - θ̇)``, clipped to the torque bound (deterministic)."""

    def forward(self, observation: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        error = goal.to(observation.dtype) - observation
        return (8.0 * error[..., :1] + 1.5 * error[..., 1:]).clamp(-2.0, 2.0)


def point_mass() -> Collector:
    return Collector(
        make_resume_env(4), reach_policy(), frames_per_batch=100, total_frames=-1, auto_register_policy_transforms=False
    )


def pendulum() -> Collector:
    policy = TensorDictModule(PendulumPD(), in_keys=["observation", "goal"], out_keys=["action"])
    return Collector(
        make_pendulum_resume_env(4), policy, frames_per_batch=80, total_frames=-1, auto_register_policy_transforms=False
    )


def parallel() -> Collector:
    return Collector(
        make_parallel_resume_env(2),
        reach_policy(),
        frames_per_batch=4 * 15,  # 15 steps a batch (worker pipes are slow: fewer steps than the others)
        total_frames=-1,
        auto_register_policy_transforms=False,
    )


def multi_sync() -> MultiSyncCollector:
    env = functools.partial(make_resume_env, 2, 2)
    return MultiSyncCollector(
        [env, env], reach_policy(), frames_per_batch=100, total_frames=-1, auto_register_policy_transforms=False
    )


def mujoco(env_id: str, randomized: bool = False) -> Collector:
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    from torchtasks.envs import gymnasium_env

    env = gymnasium_env(env_id, num_envs=3, backend="batched", num_threads=1)
    if randomized:  # per-env masses drawn at every reset, frictions redrawn every 7 steps (two transforms, two modes)
        masses = UniformDomainParam("body_mass_scale", mean=1.0, halfspan=0.3)
        env.append_transform(DomainRandomization([masses], seed=1))
        friction = NormalDomainParam("geom_friction_scale", mean=1.0, std=0.2, clip_lo=0.5, clip_up=1.5)
        env.append_transform(DomainRandomization([friction], when="interval", every=7, seed=2))
    env.append_transform(BaseEnvState())  # the preset is a finished TransformedEnv: append the base env's state
    sizes = env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1]
    torch.manual_seed(0)  # the same weights in both collectors (the checkpoint holds them too)
    net = torch.nn.Sequential(torch.nn.Linear(*sizes, dtype=torch.float64), torch.nn.Tanh())
    policy = TensorDictModule(net, ["observation"], ["action"])
    return Collector(env, policy, frames_per_batch=3 * 20, total_frames=-1, auto_register_policy_transforms=False)


# ------------------------------------------------------------------------------ the resume
def saved_and_loaded(state: dict) -> dict:
    """``torch.save`` then ``torch.load`` (``weights_only``): what a new process reads."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer)


def run_and_resume(
    make: Callable[[], Collector | MultiSyncCollector],
) -> tuple[list[TensorDictBase], list[TensorDictBase], list[TensorDictBase]]:
    """The batches before the checkpoint, the uninterrupted run's after it and the resumed run's after it."""
    running = make()
    try:
        running.set_seed(SEED)
        batches = iter(running)
        before = [next(batches).clone() for _ in range(BEFORE)]
        checkpoint = saved_and_loaded(collector_state(running))
        expected = [next(batches).clone() for _ in range(AFTER)]
    finally:
        running.shutdown()
    resumed = make()  # other generators, other initial states: only the checkpoint makes it continue
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("error", message=f".*{STALE}")  # a continued load is not stale
            load_collector_state(resumed, checkpoint)
            batches = iter(resumed)
            received = [next(batches).clone() for _ in range(AFTER)]
    finally:
        resumed.shutdown()
    return before, expected, received


def first_frames_continue(before: list[TensorDictBase], first: TensorDictBase) -> None:
    """The first frame after the checkpoint carries on the saved run's last frame, counted by hand per env.

    ``before``: the batches before the checkpoint; ``first``: the first frame after it (``[*envs]``). An env whose
    episode did not end at the last frame keeps its observation, step count, running return and trajectory id; one
    whose episode ended starts at step 0 and return 0 with a new id, larger than every id handed out before.
    """
    last = before[-1][..., -1]
    ended = last["next", "done"].squeeze(-1)  # [*envs]
    assert (~ended).any(), "no episode was in progress at the checkpoint: the test would not check a continuation"
    steps, returns, ids = last["next", "step_count"], last["next", "episode_reward"], last["collector", "traj_ids"]
    assert torch.equal(first["step_count"], torch.where(ended.unsqueeze(-1), torch.zeros_like(steps), steps))
    assert torch.equal(first["episode_reward"], torch.where(ended.unsqueeze(-1), torch.zeros_like(returns), returns))
    assert torch.equal(first["observation"][~ended], last["next", "observation"][~ended])
    new_ids = first["collector", "traj_ids"]
    assert torch.equal(new_ids[~ended], ids[~ended])
    handed_out = max(int(batch["collector", "traj_ids"].max()) for batch in before)
    assert (new_ids[ended] > handed_out).all()


def assert_continues(before, expected, received, *, traj_ids: bool = True) -> None:
    for i, (want, got) in enumerate(zip(expected, received, strict=True)):
        assert not equal_batches(want, got), f"batch {i} after the resume differs in {equal_batches(want, got)}"
        if traj_ids:
            assert torch.equal(want["collector", "traj_ids"], got["collector", "traj_ids"]), f"batch {i}: traj_ids"
    first_frames_continue(before, received[0][..., 0])


def test_a_resumed_collector_continues_the_uninterrupted_run():
    before, expected, received = run_and_resume(point_mass)
    assert_continues(before, expected, received)
    # the run-long state moved in the compared batches, so the equality says something
    data = torch.cat([b.reshape(-1) for b in expected])
    assert (data["next", "curriculum", "level"] > 0).any()
    assert data["next", "done"].any()
    assert data["next", "curriculum", "frames"].min() > BEFORE * 100  # the frame count went on


def test_a_resumed_pendulum_collector_continues_the_uninterrupted_run():
    before, expected, received = run_and_resume(pendulum)
    assert_continues(before, expected, received)
    assert torch.cat([b.reshape(-1) for b in expected])["next", "done"].any()


@pytest.mark.mujoco
@pytest.mark.parametrize("env_id", ["Hopper-v5", "HalfCheetah-v5"])
def test_a_resumed_batched_mujoco_collector_continues_the_physics(env_id: str):
    """The physics rows (with the solver's warm start) are in the checkpoint: contacts go on as uninterrupted."""
    before, expected, received = run_and_resume(functools.partial(mujoco, env_id))
    assert_continues(before, expected, received)


@pytest.mark.mujoco
def test_a_resumed_randomized_batched_mujoco_collector_continues_the_physics():
    """Per-env masses and frictions drawn by DomainRandomization: the resumed run has every env's physics and draws."""
    before, expected, received = run_and_resume(functools.partial(mujoco, "Hopper-v5", randomized=True))
    assert_continues(before, expected, received)
    data = torch.cat([b.reshape(-1) for b in expected])
    assert data["next", "done"].any()  # resets drew new masses after the checkpoint
    assert data["next", "domain", "body_mass_scale"].unique().numel() > 3


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_a_resumed_parallel_env_collector_continues_the_uninterrupted_run(fork_start_method):
    before, expected, received = run_and_resume(parallel)
    assert_continues(before, expected, received)


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_a_resumed_multi_sync_collector_continues_the_uninterrupted_run(fork_start_method):
    """Every worker's carried data is restored. New trajectory ids come from one counter the workers share in the
    order they ask, which differs from run to run: the continuing ids and the trajectory boundaries are compared."""
    before, expected, received = run_and_resume(multi_sync)
    assert_continues(before, expected, received, traj_ids=False)
    for want, got in zip(expected, received, strict=True):
        want_ids, got_ids = want["collector", "traj_ids"], got["collector", "traj_ids"]
        same_as_previous = want_ids[..., 1:] == want_ids[..., :-1]
        assert torch.equal(same_as_previous, got_ids[..., 1:] == got_ids[..., :-1])  # the same boundaries


# ------------------------------------------------------------------------------ snapshots and TorchRL's own recipe
def _frames_entry(state: dict) -> torch.Tensor:
    (frames,) = [value for key, value in state["env_state_dict"].items() if key.endswith(".frames")]
    return frames


def test_the_checkpoint_is_a_snapshot_where_state_dict_shares_live_buffers():
    collector = point_mass()
    try:
        batches = iter(collector)
        next(batches)
        live, snapshot = collector.state_dict(), collector_state(collector)
        carried = snapshot["carried"][0]["observation"].clone()
        next(batches)
        assert _frames_entry(live).item() == 200  # TorchRL's state_dict: the buffer itself, counting on
        assert _frames_entry(snapshot["state_dict"]).item() == 100
        assert torch.equal(snapshot["carried"][0]["observation"], carried)
    finally:
        collector.shutdown()


def test_torchrl_load_state_dict_without_a_reset_warns_once_and_does_not_continue():
    """The control: TorchRL's load alone keeps the fresh collector's carried data, so the batches differ."""
    running = point_mass()
    try:
        running.set_seed(SEED)
        batches = iter(running)
        for _ in range(BEFORE):
            next(batches)
        checkpoint = saved_and_loaded(collector_state(running))
        expected = [next(batches).clone() for _ in range(2)]
    finally:
        running.shutdown()
    resumed = point_mass()
    try:
        resumed.load_state_dict(checkpoint["state_dict"])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            batches = iter(resumed)
            received = [next(batches).clone() for _ in range(2)]
    finally:
        resumed.shutdown()
    stale = [w for w in caught if STALE in str(w.message)]
    assert len(stale) == 1 and stale[0].category is UserWarning  # once, though 50 steps ran after the load
    assert equal_batches(expected[0], received[0])


@pytest.mark.parametrize("after_load", ["collector.reset()", "load_collector_state"])
def test_a_reset_or_a_continuing_load_does_not_warn(after_load: str):
    running = point_mass()
    try:
        next(iter(running))
        checkpoint = saved_and_loaded(collector_state(running))
    finally:
        running.shutdown()
    resumed = point_mass()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if after_load == "collector.reset()":
                resumed.load_state_dict(checkpoint["state_dict"])
                resumed.reset()
            else:
                load_collector_state(resumed, checkpoint)
            next(iter(resumed))
    finally:
        resumed.shutdown()
    assert not [w for w in caught if STALE in str(w.message)]


# ------------------------------------------------------------------------------ refusals
def _plain_point_mass(batch: int = 4, *, state: bool = True) -> Collector:
    env = TransformedEnv(PointMassEnv(batch_size=[batch]), Compose(StepCounter(30), *([BaseEnvState()] * state)))
    policy = TensorDictModule(torch.nn.Linear(4, 2), ["observation"], ["action"])
    return Collector(env, policy, frames_per_batch=4 * batch, total_frames=-1, auto_register_policy_transforms=False)


@pytest.mark.parametrize(
    ("make_saved", "make_loading", "names"),
    [
        pytest.param(point_mass, lambda: Collector(make_resume_env(3), reach_policy(), frames_per_batch=75,
                     total_frames=-1, auto_register_policy_transforms=False),
                     ["('observation',): torch.float32 [4, 4] in the checkpoint, torch.float32 [3, 4] in this"],
                     id="other-batch"),
        pytest.param(_plain_point_mass, point_mass,
                     ["('goal',): missing in the checkpoint", "('task', 'state_des'): missing in the checkpoint"],
                     id="other-keys"),
    ],
)  # fmt: skip
def test_carried_data_of_another_configuration_are_refused_before_anything_is_loaded(make_saved, make_loading, names):
    saved_collector, loading = make_saved(), make_loading()
    try:
        next(iter(saved_collector))
        checkpoint = saved_and_loaded(collector_state(saved_collector))
        frames = loading.state_dict()["frames"]
        with pytest.raises(ValueError, match="carried data of the collector do not fit this collector's") as error:
            load_collector_state(loading, checkpoint)
        for name in names:
            assert name in str(error.value)
        assert loading.state_dict()["frames"] == frames  # nothing was loaded
    finally:
        saved_collector.shutdown()
        loading.shutdown()


def test_envs_whose_running_episodes_are_not_saved_are_refused():
    without = _plain_point_mass(state=False)  # no BaseEnvState: TorchRL saves the transforms only
    try:
        with pytest.raises(ValueError, match=r"running episodes of the collector's env \(TransformedEnv\)"):
            collector_state(without)
    finally:
        without.shutdown()
    pytest.importorskip("gymnasium")
    from torchrl.envs import GymEnv

    gym = Collector(
        TransformedEnv(GymEnv("Pendulum-v1"), Compose(StepCounter(20), BaseEnvState())),
        policy=None,
        frames_per_batch=10,
        total_frames=-1,
    )
    try:
        with pytest.raises(ValueError, match=r"running episodes of GymEnv \(at env_state_dict/transforms.1"):
            collector_state(gym)
        good = collector_state(_plain_point_mass())
        good["state_dict"] = gym.state_dict()
        with pytest.raises(ValueError, match="load_collector_state: the checkpoint does not hold the running episodes"):
            load_collector_state(gym, good)
    finally:
        gym.shutdown()


def test_collectors_that_cannot_continue_are_refused():
    assembling = Collector(
        make_resume_env(2), reach_policy(), frames_per_batch=20, total_frames=-1, trajs_per_batch=2,
        traj_format="padded", auto_register_policy_transforms=False,
    )  # fmt: skip
    try:
        with pytest.raises(ValueError, match=r"assembles trajectories \(trajs_per_batch=2\)"):
            collector_state(assembling)
    finally:
        assembling.shutdown()
    with pytest.raises(TypeError, match="must be a Collector or a MultiSyncCollector, got dict"):
        collector_state({})
    collector = point_mass()
    try:
        with pytest.raises(ValueError, match="a dict with 'state_dict' and 'carried', got \\['env_state_dict'\\]"):
            load_collector_state(collector, {"env_state_dict": {}})  # a collector.state_dict(), not collector_state
    finally:
        collector.shutdown()


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_a_multi_async_collector_and_a_shared_buffer_parallel_env_are_refused(fork_start_method):
    env = functools.partial(make_resume_env, 2, 1)
    multi_async = MultiAsyncCollector([env], reach_policy(), frames_per_batch=20, total_frames=-1)
    try:
        with pytest.raises(TypeError, match="MultiAsyncCollector cannot be checkpointed so that a resume continues"):
            collector_state(multi_async)
    finally:
        multi_async.shutdown()
    shared = Collector(
        ParallelEnv(2, functools.partial(make_resume_env, 2, 2)), reach_policy(), frames_per_batch=40,
        total_frames=-1, auto_register_policy_transforms=False,
    )  # fmt: skip
    try:
        checkpoint = collector_state(shared)
        with pytest.raises(ValueError, match=r"ParallelEnv with shared buffers cannot load.*use_buffers=False"):
            load_collector_state(shared, checkpoint)
    finally:
        shared.shutdown()


def test_a_base_env_state_of_another_env_class_is_refused():
    saved = TransformedEnv(PendulumEnv(batch_size=[2]), Compose(StepCounter(5), BaseEnvState())).state_dict()
    loading = TransformedEnv(PointMassEnv(batch_size=[2]), Compose(StepCounter(5), BaseEnvState()))
    with pytest.raises(ValueError, match="holds the state of a PendulumEnv, this env's base env is a PointMassEnv"):
        loading.load_state_dict(saved)


def test_a_state_env_refuses_another_batch_size():
    saved = PendulumEnv(batch_size=[3]).state_dict()
    with pytest.raises(ValueError, match=r"env of batch_size \[3\], this env has batch_size \[2\]"):
        PendulumEnv(batch_size=[2]).load_state_dict(saved)


@pytest.mark.mujoco
@pytest.mark.parametrize(
    ("other", "differ"),
    [
        ({"env_id": "HalfCheetah-v5"}, "env_id, frame_skip, model_sha256 differ"),
        ({"frame_skip": 5}, "frame_skip differ"),
        ({"healthy_reward": 2.0}, None),  # a reward keyword: the same simulation, the physics loads
    ],
)
def test_a_batched_mujoco_env_refuses_the_physics_of_another_simulation(other: dict, differ: str | None):
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    from torchtasks.envs import BatchedMujocoEnv

    saved_env = BatchedMujocoEnv("Hopper-v5", 2, seed=0, num_threads=1)
    saved_env.rollout(5)
    state = saved_and_loaded(saved_env.state_dict())
    kwargs = {"env_id": "Hopper-v5", **other}
    loading = BatchedMujocoEnv(kwargs.pop("env_id"), 2, seed=1, num_threads=1, **kwargs)
    try:
        if differ is None:
            loading.load_state_dict(state)
            action = TensorDict(action=torch.full(loading.action_spec.shape, 0.3), batch_size=[2])
            steps = [env.step(action.clone()) for env in (saved_env, loading)]  # from the saved state, no reset
            assert torch.equal(steps[0]["next", "qpos"], steps[1]["next", "qpos"])
            return
        with pytest.raises(ValueError, match=f"of another simulation \\({differ}\\): saved .* this env"):
            loading.load_state_dict(state)
    finally:
        saved_env.close()
        loading.close()
