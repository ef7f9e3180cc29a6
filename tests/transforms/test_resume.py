"""A stopped run resumes where it stopped: TorchRL's own recipe restores every piece of run-long state.

The recipe: ``collector.state_dict()`` -> ``torch.save`` -> a freshly built collector ->
``load_state_dict(torch.load(...))`` -> ``collector.reset()`` (TorchRL starts fresh trajectories after a
load). The reference is an uninterrupted run on which ``collector.reset()`` is called at the same frame.
With a deterministic policy, every batch after that frame must be equal bit for bit: the schedules
(frame count, gated stage and moving average), each env's level, the goals and timers the GoalCommand
draws, the initial states the base env draws, rewards and flags. Checked for a ``Collector``, a
``ParallelEnv`` inside one, and a ``MultiSyncCollector`` (every worker's state restored).
"""

from __future__ import annotations

import functools
import io
from collections.abc import Callable

import pytest
import torch
from torchrl.collectors import Collector, MultiSyncCollector

from resume_env import equal_batches, make_parallel_resume_env, make_resume_env, reach_policy

SEED = 7
BEFORE = 3  # batches collected before the checkpoint
AFTER = 3  # batches compared after it


def _single() -> Collector:
    return Collector(make_resume_env(4), reach_policy(), frames_per_batch=4 * 25, total_frames=-1)


def _parallel() -> Collector:
    return Collector(make_parallel_resume_env(2), reach_policy(), frames_per_batch=4 * 25, total_frames=-1)


def _multi_sync() -> MultiSyncCollector:
    env = functools.partial(make_resume_env, 2, 2)
    return MultiSyncCollector([env, env], reach_policy(), frames_per_batch=4 * 25, total_frames=-1)


def _resume_matches_uninterrupted(make: Callable[[], Collector | MultiSyncCollector]) -> dict:
    """The resumed run's batches equal the uninterrupted run's; returns the checkpoint as loaded."""
    reference = make()
    try:
        reference.set_seed(SEED)
        reference.reset()  # the collector reset its envs when it was built, before they were seeded
        batches = iter(reference)
        before = [next(batches).clone() for _ in range(BEFORE)]
        reference.reset()  # where the resumed run starts its fresh trajectories
        expected = [next(batches).clone() for _ in range(AFTER)]
    finally:
        reference.shutdown()

    stopped = make()
    try:
        stopped.set_seed(SEED)
        stopped.reset()
        batches = iter(stopped)
        stopped_before = [next(batches).clone() for _ in range(BEFORE)]
        buffer = io.BytesIO()
        torch.save(stopped.state_dict(), buffer)
    finally:
        stopped.shutdown()
    assert all(not equal_batches(a, b) for a, b in zip(before, stopped_before, strict=True))  # same seed, same run

    resumed = make()  # a fresh collector: its envs reset with fresh generators when it was built
    try:
        buffer.seek(0)
        checkpoint = torch.load(buffer, weights_only=False)
        resumed.load_state_dict(checkpoint)
        resumed.reset()
        batches = iter(resumed)
        received = [next(batches).clone() for _ in range(AFTER)]
    finally:
        resumed.shutdown()

    for i, (want, got) in enumerate(zip(expected, received, strict=True)):
        assert not equal_batches(want, got), f"batch {i} after the resume differs in {equal_batches(want, got)}"
    # the run-long state did move in the compared batches, so the equality says something
    data = torch.cat([b.reshape(-1) for b in expected])
    assert (data["next", "curriculum", "level"] > 0).any()
    assert data["next", "done"].any()
    frames = data["next", "curriculum", "frames"]
    assert frames.min() > BEFORE * 100  # the frame count went on from the checkpoint, not from 0
    return checkpoint


#: where make_resume_env's BaseEnvState keeps the base env's state (its reset generator and seed)
BASE_ENV_STATE = "transforms.6._extra_state"


def test_collector_resumes_bit_for_bit():
    _resume_matches_uninterrupted(_single)


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_parallel_env_in_a_collector_resumes_bit_for_bit(fork_start_method):
    workers = _resume_matches_uninterrupted(_parallel)["env_state_dict"]
    assert set(workers) == {"worker0", "worker1"}
    seeds = [workers[f"worker{i}"][BASE_ENV_STATE]["_extra_state"]["seed"] for i in range(2)]
    assert seeds[0] != seeds[1]  # each worker's base env, seeded by set_seed with its own seed


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
def test_multi_sync_collector_resumes_bit_for_bit(fork_start_method):
    checkpoint = _resume_matches_uninterrupted(_multi_sync)
    assert all(BASE_ENV_STATE in checkpoint[f"worker{i}"]["env_state_dict"] for i in range(2))


def test_a_resume_without_the_checkpoint_differs():
    """The comparison can fail: a fresh collector with the same seed but no loaded state collects other data."""
    reference = _single()
    fresh = _single()
    try:
        reference.set_seed(SEED)
        reference.reset()
        batches = iter(reference)
        for _ in range(BEFORE):
            next(batches)
        reference.reset()
        expected = next(batches).clone()
        fresh.set_seed(SEED)
        fresh.reset()
        received = next(iter(fresh)).clone()
    finally:
        reference.shutdown()
        fresh.shutdown()
    assert equal_batches(expected, received)
