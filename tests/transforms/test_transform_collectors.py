"""The same task in every TorchRL execution mode: identical per-env results, nothing dropped.

Each env is a :class:`~replay_env.ReplayEnv` of a golden scenario (success, failure and time-limit
episodes, so the task ends episodes and TorchRL resets them) driven by the replay policy; env ``i``
starts at golden episode ``i``. Whatever runs it (``env.rollout``, ``SerialEnv``/``ParallelEnv`` with the
transform inside the workers or outside on the batch, ``Collector``, ``MultiSyncCollector``,
``MultiAsyncCollector``, ``Collector(backend="ray")``), every collected transition must

- carry Pyrado's numbers for its episode and step (reward, done, success, failure, breakdown),
- be recomputed exactly from the stored state/action/memory by ``TaskTransform.forward``,
- belong to an unbroken sequence of frames per env (no frame dropped or repeated),
- equal the transition of a plain single-env ``env.rollout`` at the same frame (memory included).

Multi-process envs and collectors get spawn-safe constructors (``functools.partial`` of module-level
functions of ``replay_env``).
"""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.envs import ParallelEnv, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from replay_env import (
    frame_problems,
    frames_by_env,
    make_replay_env,
    make_task_env,
    missing_frames,
    recomputation_problems,
    replay_policy,
    task_transforms,
)

NAME = "final_rew/default"  # episodes of 7 (success), 4 (failure) and 20 (time limit) steps
NUM_ENVS = 2
STEPS = 40  # per env: more than one cycle through the three episodes

#: keys compared between execution modes
COMPARED = [
    "observation",
    "action",
    "episode",
    "t",
    "step_count",
    "task",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
    ("next", "success"),
    ("next", "failure"),
    ("next", "task"),
    ("next", "task_reward"),
]


def _env_fns(factory=make_task_env) -> list[functools.partial]:
    return [functools.partial(factory, NAME, i, i) for i in range(NUM_ENVS)]


@functools.cache
def _reference(env_id: int, steps: int) -> TensorDictBase:
    """The plain single-env rollout of env ``env_id`` (the results every mode must reproduce)."""
    env = make_task_env(NAME, env_id, env_id)
    return env.rollout(steps, replay_policy(), break_when_any_done=False)


@pytest.fixture
def keep_threads():
    """Collectors change the number of torch threads of the main process; restore it."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def _check(data: TensorDictBase, *, envs: tuple[int, ...] | None, min_frames_per_env: int = 0) -> None:
    """Golden numbers, offline recomputation, no dropped frames, same as the single-env rollout."""
    problems = frame_problems(data, NAME)
    assert not problems, "\n".join(problems)
    problems = recomputation_problems(data, NAME)
    assert not problems, "\n".join(problems)
    problems = missing_frames(data)
    assert not problems, "\n".join(problems)
    per_env = frames_by_env(data)
    if envs is not None:
        assert tuple(per_env) == envs, f"frames of envs {list(per_env)}, expected {list(envs)}"
    for env_id, frames in per_env.items():
        n = frames.shape[0]
        assert n >= min_frames_per_env, f"env {env_id}: only {n} frames"
        reference = _reference(env_id, max(n, STEPS))[:n]
        for key in COMPARED:
            got, want = frames.get(key), reference.get(key)
            if isinstance(want, TensorDictBase):
                same = (got == want).all()
            else:
                same = torch.equal(got, want)
            assert same, f"env {env_id}: {key} differs from the single-env rollout"
    ends = data.get(("next", "done")).sum().item()
    assert ends >= 2, f"only {ends} episode ends in the data"


# --------------------------------------------------------------------------------------------------
# In-process
# --------------------------------------------------------------------------------------------------


def test_single_env_rollout() -> None:
    for env_id in range(NUM_ENVS):
        data = _reference(env_id, STEPS)
        assert data.shape == (STEPS,)
        _check(data, envs=(env_id,))
    check_env_specs(make_task_env(NAME), seed=None)


@pytest.mark.parametrize("transform_inside", [True, False], ids=["inside", "outside"])
def test_serial_env(transform_inside: bool) -> None:
    env = _batched_env(SerialEnv, transform_inside)
    check_env_specs(env, seed=None)
    env = _batched_env(SerialEnv, transform_inside)
    data = env.rollout(STEPS, replay_policy(), break_when_any_done=False)
    assert data.shape == (NUM_ENVS, STEPS)
    _check(data, envs=(0, 1), min_frames_per_env=STEPS)


def _batched_env(cls, transform_inside: bool, **kwargs):
    if transform_inside:
        return cls(NUM_ENVS, _env_fns(make_task_env), **kwargs)
    return TransformedEnv(cls(NUM_ENVS, _env_fns(make_replay_env), **kwargs), task_transforms(NAME))


def test_collector(keep_threads) -> None:
    collector = Collector(
        functools.partial(make_task_env, NAME, 0, 0), replay_policy(), frames_per_batch=16, total_frames=64
    )
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    assert [batch.numel() for batch in batches] == [16] * 4
    data = torch.cat([batch.reshape(-1) for batch in batches])
    _check(data, envs=(0,), min_frames_per_env=64)


@pytest.mark.quick
def test_collector_on_batched_env(keep_threads) -> None:
    collector = Collector(
        functools.partial(_batched_env, SerialEnv, False), replay_policy(), frames_per_batch=32, total_frames=96
    )
    try:
        data = torch.cat([batch.clone() for batch in collector], dim=-1)
    finally:
        collector.shutdown()
    assert data.shape == (NUM_ENVS, 48)
    _check(data, envs=(0, 1), min_frames_per_env=48)


def test_checks_can_fail() -> None:
    """Dropping a frame, a wrong reward and a stale memory are all detected."""
    data = _reference(0, STEPS).clone()
    assert missing_frames(torch.cat([data[:5], data[6:]]))
    broken = data.clone()
    broken["next", "reward"][3] += 1e-3
    assert frame_problems(broken, NAME) and recomputation_problems(broken, NAME)
    broken = data.clone()
    broken["task", "wrapped", "state_des"][2] += 1.0  # the memory the reward is recomputed from
    assert recomputation_problems(broken, NAME)


# --------------------------------------------------------------------------------------------------
# Multi-process
# --------------------------------------------------------------------------------------------------


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
@pytest.mark.parametrize("transform_inside", [True, False], ids=["inside", "outside"])
def test_parallel_env(transform_inside: bool, keep_threads) -> None:
    env = _batched_env(ParallelEnv, transform_inside, mp_start_method="fork")
    try:
        data = env.rollout(STEPS, replay_policy(), break_when_any_done=False)
        check_env_specs(env, seed=None)  # after the rollout: it moves the envs on
    finally:
        env.close()
    assert data.shape == (NUM_ENVS, STEPS)
    _check(data, envs=(0, 1), min_frames_per_env=STEPS)


@pytest.mark.multiprocess
@pytest.mark.slow
@pytest.mark.xdist_group("multiprocess")
def test_parallel_env_spawn(keep_threads) -> None:
    """A spawned worker rebuilds env, task and transform from the pickled ``functools.partial`` constructor.

    One worker (env 1, starting at the second golden episode): spawning costs seconds per process.
    """
    env = ParallelEnv(1, [functools.partial(make_task_env, NAME, 1, 1)], mp_start_method="spawn")
    try:
        data = env.rollout(STEPS, replay_policy(), break_when_any_done=False)
    finally:
        env.close()
    assert data.shape == (1, STEPS)
    _check(data, envs=(1,), min_frames_per_env=STEPS)


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
@pytest.mark.parametrize("cls", [MultiSyncCollector, MultiAsyncCollector], ids=["sync", "async"])
def test_multi_collector(cls, keep_threads, fork_start_method) -> None:
    collector = cls(_env_fns(), replay_policy(), frames_per_batch=40, total_frames=160)
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    data = torch.cat([batch.reshape(-1) for batch in batches])
    assert data.numel() == 160, data.numel()
    if cls is MultiSyncCollector:
        _check(data, envs=(0, 1), min_frames_per_env=80)
    else:  # the async collector yields whichever worker is ready
        _check(data, envs=None)


# the test's policy is a plain callable with no weights: TorchRL's notices about syncing weights do not apply
@pytest.mark.filterwarnings("ignore:The policy is not an nn.Module:UserWarning")
@pytest.mark.filterwarnings("ignore:RayCollector iteration started before weight synchronization:UserWarning")
@pytest.mark.ray
@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_ray_collector(keep_threads, ray_cluster) -> None:
    """Two Ray actors, each collecting from a replay env built from a ``functools.partial`` of ``make_task_env``
    (a module of ``tests/``, on the actors' ``PYTHONPATH``: see the ``ray_cluster`` fixture)."""
    collector = Collector(
        _env_fns(),
        replay_policy(),
        backend="ray",
        frames_per_batch=40,
        total_frames=120,
        remote_configs={"num_cpus": 1, "memory": 512 * 1024**2},
    )
    try:
        batches = [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
    data = torch.cat([batch.reshape(-1) for batch in batches])
    assert data.numel() == 120, data.numel()
    _check(data, envs=None)
