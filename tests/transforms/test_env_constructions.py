"""Batched envs built from a lambda, an ``EnvCreator`` and a ``functools.partial`` run and resume alike.

TorchRL's ``ParallelEnv`` wraps a lambda in an ``EnvCreator``, which builds a first env, drops the tensors of its
``state_dict()`` and loads what is left into every env it makes, with ``strict=False``: each stateful transform
(randomization, commands, curricula, levels, the base env's state, the task's reward groups) must take that
partial load. For every feature env of the invariant suite (each ends in a ``BaseEnvState``), ``SerialEnv`` of the
three constructions collects the same batches with the same seed, and a checkpoint saved in one construction
(:func:`collector_state`) resumes in another. ``ParallelEnv`` takes the same load in its workers; one
``ParallelEnv`` per construction over an env holding every stateful transform at once keeps the processes few.
"""

from __future__ import annotations

import copy
import functools
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs import EnvCreator, ParallelEnv, SerialEnv

import feature_envs
from feature_envs import FEATURES
from resume_env import equal_batches
from torchtasks.transforms import collector_state, load_collector_state

WORKERS = 2
BATCH = 2  # envs per worker
STEPS = 6  # frames per env and batch: the feature envs' episodes (at most 12 steps) cross the batches
SEED = 5

Make = Callable[[], object]


def _lambda(make: functools.partial) -> Make:
    return lambda: make()  # a lambda: ParallelEnv wraps it in an EnvCreator itself


CONSTRUCTIONS: dict[str, Callable[[functools.partial], Make]] = {
    "lambda": _lambda,
    "env_creator": EnvCreator,
    "partial": lambda make: make,
}


def _run(batched: Callable[[Make], object], factory: Callable, policy) -> None:
    """Each construction collects two batches (a checkpoint after the first) and then, loading the checkpoint of the
    construction before it, the second batch again: the batches and the resumes are the same in all of them."""
    make = functools.partial(factory, BATCH, SEED)
    collectors, runs = {}, {}
    try:
        for name, construct in CONSTRUCTIONS.items():
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", "A lambda function was passed to ParallelEnv", UserWarning)
                env = batched(construct(make))
            # seeded before its first reset (which the Collector makes): an EnvCreator gives every env it makes the
            # generators of its first env, reset and stepped once; the seed decides them all
            env.set_seed(SEED)
            frames = env.batch_size.numel() * STEPS
            collectors[name] = Collector(
                env, policy, frames_per_batch=frames, total_frames=-1, auto_register_policy_transforms=False
            )
            batches = iter(collectors[name])
            first = next(batches).clone()
            runs[name] = (first, collector_state(collectors[name]), next(batches).clone())
        names = list(runs)
        first, _, second = runs[names[0]]
        for name in names[1:]:
            assert equal_batches(runs[name][0], first) == [], f"{name}: the first batch differs from {names[0]}'s"
            assert equal_batches(runs[name][2], second) == [], f"{name}: the second batch differs from {names[0]}'s"
        for saved, loaded in zip(names, names[1:] + names[:1], strict=True):
            load_collector_state(collectors[loaded], runs[saved][1])
            resumed = next(iter(collectors[loaded])).clone()
            assert equal_batches(resumed, runs[saved][2]) == [], f"saved in {saved}, resumed in {loaded}: differs"
    finally:
        for collector in collectors.values():
            collector.shutdown()


@pytest.mark.parametrize("name", list(FEATURES))
def test_serial_envs_of_every_construction_run_and_resume_alike(name: str):
    feature = FEATURES[name]
    _run(functools.partial(SerialEnv, WORKERS), feature.make_env, feature.make_policy())


def _same(first: Any, second: Any) -> bool:
    """Equal state dicts: the same keys, tensors equal bit for bit, nested dicts alike."""
    if isinstance(first, Mapping):
        return (
            isinstance(second, Mapping)
            and first.keys() == second.keys()
            and all(_same(first[key], second[key]) for key in first)
        )
    if isinstance(first, torch.Tensor):
        return isinstance(second, torch.Tensor) and torch.equal(first, second)
    return first == second


def test_a_partial_load_keeps_the_checks_of_what_it_holds():
    """EnvCreator's state (no tensors) loads only without strict; an entry of another configuration is refused."""
    make = functools.partial(FEATURES["domain"].make_env, BATCH, SEED)
    partial = EnvCreator(make).state_dict()  # what an EnvCreator loads into every env it makes
    assert not any(isinstance(value, torch.Tensor) for value in partial.values())
    env = make()
    env.reset()
    before = copy.deepcopy(env.state_dict())
    with pytest.raises(ValueError, match=r"DomainRandomization\.load_state_dict: the saved distribution"):
        env.load_state_dict(partial)  # strict: a partial checkpoint is refused
    key = next(key for key, value in partial.items() if isinstance(value, Mapping) and value.get("when") == "reset")
    other = {**partial, key: {**partial[key], "when": "startup"}}
    with pytest.raises(ValueError, match="when: saved 'startup', here 'reset'"):
        env.load_state_dict(other, strict=False)
    assert _same(env.state_dict(), before)
    env.load_state_dict(partial, strict=False)  # accepted: the configuration is this one


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_parallel_envs_of_every_construction_run_and_resume_alike(fork_start_method):
    # without shared buffers: TorchRL 0.14.1's ParallelEnv.load_state_dict leaves stale done flags with them (see
    # torchtasks.transforms.checkpoint); the workers build, seed, step and load their envs as with them. One worker
    # each: a worker process builds its env from the construction as any other does (the SerialEnv cases run two
    # workers with their consecutive seeds), and every process costs seconds here
    parallel = functools.partial(ParallelEnv, 1, use_buffers=False)
    _run(parallel, feature_envs.every_run_state, feature_envs.pendulum_policy())
