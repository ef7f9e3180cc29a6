"""Batch independence: a batch of environments behaves exactly like one batch-1 run per environment.

Random task trees (``task_trees.task_trees``) are driven with the transform's protocol (step reward,
done = task done | time limit, final reward, partial reset with per-env overrides) on a batch of
N environments with different states, actions, remaining steps, episode ends and reset goals. The
same task object is then driven on each environment alone. Rewards, flags and final rewards must
be bitwise equal (float64): every task op is elementwise or a reduction over the last dim of one
row, so no op-order difference between batch sizes is expected and none is tolerated (an
exploratory run of 400 random trees of depth 4 found none).

Hypothesis runs derandomized (fixed examples, stable runtime); raise ``max_examples`` or drop
``derandomize`` locally to explore more trees.
"""

from __future__ import annotations

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from task_trees import (
    assert_memory_equal,
    assert_same,
    drive,
    example_trees,
    make_drive_data,
    reshape_envs,
    select_env,
    task_trees,
)

SETTINGS = settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,
)
FIELDS = ("reward", "success", "failure", "done", "final")


def _assert_batch_equals_singles(task, data, reward_on: str, description: str, terms: bool = False) -> None:
    batch = drive(task, data, reward_on=reward_on, terms=terms)
    assert set(batch.terms) == (set(task.term_names) if terms else set())
    for i in range(data.batch_shape[0]):
        single = drive(task, select_env(data, i), reward_on=reward_on, terms=terms)
        for name in FIELDS:
            assert_same(getattr(batch, name)[:, i], getattr(single, name)[:, 0], f"{description} env {i} {name}")
        for name, value in batch.terms.items():
            assert_same(value[:, i], single.terms[name][:, 0], f"{description} env {i} term {name}")
        assert_memory_equal(batch.memory[i], single.memory[0], f"{description} env {i} final")


@SETTINGS
@given(
    tree=task_trees(max_depth=3),
    n_envs=st.integers(2, 6),
    steps=st.integers(4, 12),
    seed=st.integers(0, 2**31 - 1),
    reward_on=st.sampled_from(["next", "state"]),
    use_overrides=st.booleans(),
    terms=st.booleans(),
)
def test_batch_equals_separate_single_env_runs(tree, n_envs, steps, seed, reward_on, use_overrides, terms):
    task, description = tree
    data = make_drive_data(task, n_envs, steps, seed, use_overrides=use_overrides)
    _assert_batch_equals_singles(task, data, reward_on, description, terms)


@settings(SETTINGS, max_examples=15)
@given(
    tree=task_trees(max_depth=3),
    n_envs=st.integers(2, 6),
    seed=st.integers(0, 2**31 - 1),
    use_overrides=st.booleans(),
)
def test_partial_reset_touches_only_reset_rows(tree, n_envs, seed, use_overrides):
    task, description = tree
    data = make_drive_data(task, n_envs, 8, seed, use_overrides=use_overrides)
    calls = []

    def check(before, fresh, after, done):
        calls.append(done)
        keep = ~done
        assert_memory_equal(after[keep], before[keep], f"{description}: rows not reset")
        assert_memory_equal(after[done], fresh[done], f"{description}: reset rows")
        # the partial reset builds new memory: the old one is not modified in place
        assert after is not before

    drive(task, data, on_reset=check)
    assert len(calls) == 8


@pytest.mark.parametrize("name", sorted(example_trees()))
def test_memory_is_never_modified_in_place(name):
    """Every step returns new memory: memory objects seen earlier keep their values to the end."""
    task = example_trees()[name]
    data = make_drive_data(task, 4, 6, seed=1)
    snapshots = []

    def keep(before, fresh, after, done):
        snapshots.extend((memory, memory.clone()) for memory in (before, fresh, after))

    drive(task, data, on_reset=keep)
    for memory, copy in snapshots:
        assert_memory_equal(memory, copy, f"{name}: memory modified after it was returned")


@pytest.mark.parametrize("name", sorted(example_trees()))
@pytest.mark.parametrize("reward_on", ["next", "state"])
def test_two_batch_dims_equal_flattened_run(name, reward_on):
    task = example_trees()[name]
    data = make_drive_data(task, 6, 12, seed=7)
    flat = drive(task, data, reward_on=reward_on)
    grid = drive(task, reshape_envs(data, (2, 3)), reward_on=reward_on)
    for field in FIELDS:
        assert getattr(grid, field).shape == (12, 2, 3)
        assert_same(getattr(grid, field).reshape(12, 6), getattr(flat, field), f"{name} {field}")
    assert grid.memory.batch_size == (2, 3)
    assert_memory_equal(grid.memory.reshape(6), flat.memory, f"{name} memory")


@pytest.mark.parametrize("name", sorted(example_trees()))
def test_example_trees_batch_equals_single_runs(name):
    task = example_trees()[name]
    data = make_drive_data(task, 6, 12, seed=3)
    _assert_batch_equals_singles(task, data, "next", name)


def test_example_trees_exercise_every_kind_of_episode_end():
    """The driver is only a good test if successes, failures, truncations and final rewards all occur."""
    seen = {"success": 0, "failure": 0, "truncated": 0, "final": 0, "override_reset": 0}
    for name, task in example_trees().items():
        data = make_drive_data(task, 6, 12, seed=3)
        result = drive(task, data)
        seen["success"] += int(result.success.sum())
        seen["failure"] += int(result.failure.sum())
        seen["truncated"] += int((result.done & ~result.success & ~result.failure).sum())
        seen["final"] += int((result.final != 0).sum())
        seen["override_reset"] += int(bool(data.overrides[1]) and result.done.any())
        assert not torch.isnan(result.reward).any(), name
    assert all(count > 0 for count in seen.values()), seen


@pytest.mark.quick
def test_one_env_data_does_not_leak_into_others():
    """Changing environment 0's states changes nothing for environments 1..N-1."""
    task = example_trees()["sequential_nested"]
    data = make_drive_data(task, 4, 10, seed=11)
    base = drive(task, data)
    data.states[:, 0] = 5.0 * data.states[:, 0] + 1.0
    data.reset_states[:, 0] = -data.reset_states[:, 0]
    data.limit[0] = 2
    changed = drive(task, data)
    assert not torch.equal(changed.reward[:, 0], base.reward[:, 0])
    for field in FIELDS:
        assert_same(getattr(changed, field)[:, 1:], getattr(base, field)[:, 1:], field)
