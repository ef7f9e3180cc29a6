"""Every wrapper and composite around a memory-less task runs in ``SerialEnv`` and ``ParallelEnv``.

A memory-less task (a goalless task with a stateless reward, a condition, an optimization) has an empty memory; a
wrapper keeps its latch beside it (``{"paid", "wrapped": {}}``), a composite its flags. TorchRL's batched envs
refuse an empty Composite in the specs, and its ``RemoveEmptySpecs`` puts empty nodes back by replacing their parent
(the latch with it): the env data hold the memory without its empty sub-memories. For every such tree
(:func:`task_trees.around_memoryless_cases`) the batched env passes ``check_env_specs``, each of its workers
rolls out what the env alone rolls out (also with ``RemoveEmptySpecs`` appended), and a TaskTransform recomputing
the collected transitions offline reads their memory back.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import pytest
from torchrl.envs import Compose, ParallelEnv, RewardSum, SerialEnv, StepCounter, TransformedEnv
from torchrl.envs.transforms import RemoveEmptySpecs
from torchrl.envs.utils import check_env_specs

from feature_envs import point_policy
from resume_env import equal_batches
from task_trees import around_memoryless_cases
from torchtasks.envs import PointMassEnv
from torchtasks.tasks import Task
from torchtasks.transforms import TaskTransform

CASES = around_memoryless_cases()
BATCH = 3
MAX_STEPS = 3
STEPS = 6  # episodes of at most MAX_STEPS steps: resets of some envs while others run


def _env(build: Callable[[], Task], remove_empty: bool = False) -> TransformedEnv:
    transforms = [StepCounter(MAX_STEPS), TaskTransform(build()), RewardSum()]
    return TransformedEnv(
        PointMassEnv(batch_size=[BATCH], seed=0, max_force=2.0),
        Compose(*transforms, *([RemoveEmptySpecs()] if remove_empty else [])),
    )


def _check_batched(batched, build: Callable[[], Task]) -> None:
    """Each worker's rollout equals the env's alone (every worker starts from the same seed); then the specs."""
    policy = point_policy(False)
    expected = _env(build).rollout(STEPS, policy, break_when_any_done=False)
    removed = _env(build, remove_empty=True).rollout(STEPS, policy, break_when_any_done=False)
    assert equal_batches(removed, expected) == [], "RemoveEmptySpecs changed the rollout"
    data = batched.rollout(STEPS, policy, break_when_any_done=False)
    for worker in range(data.shape[0]):
        assert equal_batches(data[worker], expected) == [], f"worker {worker}"
    recomputed = TaskTransform(build(), max_steps=MAX_STEPS)(data.clone())  # offline: the stored memory read back
    assert equal_batches(recomputed, data) == [], "offline recomputation"
    check_env_specs(batched, seed=0)


@pytest.mark.parametrize("name", list(CASES))
def test_serial_envs_run_every_tree_around_a_memoryless_task(name: str):
    batched = SerialEnv(2, functools.partial(_env, CASES[name]))
    try:
        _check_batched(batched, CASES[name])
    finally:
        batched.close()


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_a_parallel_env_runs_a_tree_nesting_them(fork_start_method):
    # one tree with empty sub-memories under a latch, under composites' flags and under both at once: the transform
    # strips and restores them by path whatever the tree, so a ParallelEnv (its shared buffers made from the specs,
    # its workers' data sent through them) of this tree covers what a ParallelEnv adds to the SerialEnv cases
    batched = ParallelEnv(2, functools.partial(_env, CASES["nested"]))
    try:
        _check_batched(batched, CASES["nested"])
    finally:
        batched.close()
