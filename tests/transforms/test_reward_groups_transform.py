"""Reward groups through every task class in a TaskTransform, TorchRL's transforms after it, and no cost without them.

For every case of ``task_trees.all_task_cases()`` (leaves, wrappers, composites, shaping, masks, final rewards,
flipping, ...) a :class:`RewardGroupsTask` over the case's sources (its named terms, ``"step"``, ``"final"`` and a
term of the groups' own) runs in a TaskTransform over a point-mass env. The written vector reward is checked
against groups computed here, with numpy, from the breakdown entries the same transform wrote: numpy's in-place
``vec += c * value`` on a vector of the narrower of the groups' and the terms' dtype, source after source, then
cast to the groups' dtype (the documented accumulation; with float32 groups over float64 terms, MO-Gymnasium's
arithmetic). Then TorchRL's ``RewardSum`` and ``LineariseRewards`` over the vector, the refused key collisions,
and trees without groups: no group entry, no group call.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
import torch
from torchrl.envs import Compose, LineariseRewards, RewardSum, StepCounter, TransformedEnv

from task_trees import STATE_LABELS, all_task_cases, full_spec, random_transitions
from torchtasks.envs import PointMassEnv
from torchtasks.rewards import VelocityReward
from torchtasks.tasks import MaskedTask, RewardGroupsTask, Task
from torchtasks.transforms import TaskTransform

CASES = all_task_cases()
BATCH, STEPS, LIMIT = 4, 12, 8  # episodes end by the task, the bounds and the StepCounter's limit within the rollout
#: (the env's dtype: the state's, the terms' and the reward's; the groups' dtype): one per case, in turn
DTYPES = [(torch.float64, torch.float32), (torch.float32, None), (torch.float64, None), (torch.float32, torch.float64)]
OWN = 0.5  # the groups' own term: OWN * the next state's entry it reads (Grouped.own_index)


def _groups(task: Task) -> dict[str, dict[str, float]]:
    """Groups over every source of ``task`` (dyadic coefficients: exact in float32), terms in reverse order."""
    terms = task.term_names
    groups = {"whole": {"step": 1.0, "final": 1.0}}  # the reward itself
    if terms:
        groups["terms"] = {name: 0.5 + i for i, name in enumerate(reversed(terms))}
    groups["mixed"] = {"final": -2.0, "own": 1.5, "step": 0.25, **({terms[0]: 3.0} if terms else {})}
    return groups


class Grouped(NamedTuple):
    task: Task
    groups: dict[str, dict[str, float]]
    #: the entry of the env's state the groups' own term reads
    own_index: int


def _grouped(name: str, dtype: torch.dtype | None) -> Grouped:
    """The case in a RewardGroupsTask; a case of another state size (a flip of one angle) is grouped inside a mask of
    the env's state ``b``, so its groups' own term reads that entry."""
    task = CASES[name]()
    groups = _groups(task)
    grouped = RewardGroupsTask(task, groups, terms={"own": VelocityReward(OWN, index=0)}, dtype=dtype)
    if task.state_size == full_spec().state_size:
        return Grouped(grouped, groups, 0)
    return Grouped(MaskedTask(full_spec(), grouped, ["b"]), groups, STATE_LABELS.index("b"))


def _env(task: Task, env_dtype: torch.dtype, **kwargs) -> TransformedEnv:
    transforms = Compose(StepCounter(LIMIT), TaskTransform(task, **kwargs), RewardSum())
    return TransformedEnv(PointMassEnv(batch_size=[BATCH], seed=0, max_force=2.0, dtype=env_dtype), transforms)


def _rollout(env: TransformedEnv):
    env.set_seed(0)  # the initial states
    torch.manual_seed(0)  # the random actions
    return env.rollout(STEPS, break_when_any_done=False)


def _sources(data, task: Task, own_index: int) -> dict[str, np.ndarray]:
    """Every source of the groups as written (or, where not written, as the docs define it), ``[B, T]``."""
    nxt = data["next"]
    reward = nxt["reward"][..., 0].numpy()
    if task.pays_final_reward:
        step, final = nxt["task_reward", "step"][..., 0].numpy(), nxt["task_reward", "final"][..., 0].numpy()
    else:  # no breakdown of step and final: the step reward is the reward, the final reward 0
        step, final = reward, np.zeros_like(reward)
    sources = {"step": step, "final": final, "own": OWN * nxt["observation"][..., own_index].numpy()}
    sources.update({name: nxt["task_reward", name][..., 0].numpy() for name in task.term_names})
    return sources


def _expected_group(weights: dict[str, float], sources: dict[str, np.ndarray], dtype: torch.dtype) -> torch.Tensor:
    """numpy's in-place adds on a vector of the narrower of the groups' and the terms' dtype, cast to the groups'."""
    terms_dtype = next(iter(sources.values())).dtype
    group_dtype = np.dtype(str(dtype).removeprefix("torch."))
    vec = np.zeros(next(iter(sources.values())).shape, dtype=min(group_dtype, terms_dtype, key=lambda d: d.itemsize))
    for source, coefficient in weights.items():
        vec += coefficient * sources[source]
    return torch.from_numpy(vec.astype(group_dtype))


@pytest.mark.parametrize("name", sorted(CASES))
def test_every_task_class_writes_its_groups(name: str) -> None:
    env_dtype, group_dtype = DTYPES[sorted(CASES).index(name) % len(DTYPES)]
    task, groups, own_index = _grouped(name, group_dtype)
    env = _env(task, env_dtype)
    env.check_env_specs()
    written = group_dtype or env_dtype
    assert task.group_names == tuple(groups) and task.facts.has_groups
    assert env.full_reward_spec["vector_reward"].shape == (BATCH, len(groups))
    assert env.full_reward_spec["vector_reward"].dtype == written
    assert {env.full_reward_spec["reward_groups", group].shape for group in groups} == {torch.Size([BATCH, 1])}
    data = _rollout(env)
    assert bool(data["next", "done"].any()), "no episode ended: the final reward is never paid"
    vector = data["next", "vector_reward"]
    assert vector.shape == (BATCH, STEPS, len(groups)) and vector.dtype == written
    sources = _sources(data, task, own_index)
    for i, (group, weights) in enumerate(groups.items()):
        expected = _expected_group(weights, sources, written)
        assert torch.equal(vector[..., i], expected), f"{name}: group {group!r}"
        assert torch.equal(data["next", "reward_groups", group][..., 0], expected), f"{name}: entry {group!r}"
    if group_dtype is None:  # step + final in the reward's dtype: the reward
        assert torch.equal(vector[..., 0], data["next", "reward"][..., 0])

    # offline: forward() and relabel() rewrite every group entry, through the same evaluation
    transform = env.transform[1]
    keys = [("next", "vector_reward"), *(("next", "reward_groups", group) for group in groups)]
    for rewrite in (transform.forward, transform.relabel):
        stored = data.clone()
        for key in keys:
            stored[key] = torch.full_like(stored[key], float("nan"))
        rewrite(stored)
        for key in keys:
            assert torch.equal(stored[key], data[key]), f"{name}: {rewrite.__name__} left {key!r} as it was"

    # without the breakdown, the groups are written all the same
    quiet = _rollout(_env(_grouped(name, group_dtype).task, env_dtype, log_terms=False))
    assert "task_reward" not in quiet["next"].keys()
    assert torch.equal(quiet["next", "vector_reward"], vector)


# ---------------------------------------------------------------------------------------------- TorchRL after it
COMPOSED = "final_state_goalless"  # named terms (forward, ctrl) and a state-dependent final reward


def test_reward_sum_sums_the_vector_per_episode_and_linearise_rewards_weighs_it() -> None:
    weights = [0.5, -1.0, 2.0]
    task = _grouped(COMPOSED, None).task
    env = TransformedEnv(
        PointMassEnv(batch_size=[BATCH], seed=0, max_force=2.0),
        Compose(
            StepCounter(LIMIT),
            TaskTransform(task),
            RewardSum(),
            LineariseRewards(in_keys=["vector_reward"], out_keys=["weighted"], weights=weights),
        ),
    )
    env.check_env_specs()
    data = _rollout(env)
    nxt = data["next"]
    vector, done = nxt["vector_reward"], nxt["done"][..., 0]
    assert int(done.sum()) >= 2  # resets inside the rollout
    # the running sum, counted frame by frame: 0 again after each episode end
    running, sums = torch.zeros(BATCH, 3), []
    for t in range(STEPS):
        running = running + vector[:, t]
        sums.append(running)
        running = torch.where(done[:, t, None], torch.zeros_like(running), running)
    episode = nxt["episode_vector_reward"]
    assert episode.shape == (BATCH, STEPS, 3)
    assert torch.equal(episode, torch.stack(sums, 1))
    for i, group in enumerate(task.group_names):
        assert torch.equal(nxt["reward_groups", f"episode_{group}"][..., 0], episode[..., i])
    expected = sum(w * vector[..., i].double() for i, w in enumerate(weights))
    torch.testing.assert_close(nxt["weighted"][..., 0].double(), expected, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize(
    ("groups", "kwargs", "match"),
    [
        (
            {"a": {"step": 1.0}},
            {"vector_reward_key": "reward"},
            r"reward_key='reward' collides with vector_reward_key='reward'",
        ),
        ({"a": {"step": 1.0}}, {"groups_key": "task_reward"}, r"terms_key='task_reward' collides with groups_key"),
        (
            {"a": {"step": 1.0}},
            {"terms_key": ("out", "terms"), "groups_key": "out"},
            r"terms_key=\('out', 'terms'\) collides with groups_key='out'",
        ),
        ({"a": {"step": 1.0}}, {"vector_reward_key": "reward_groups"}, r"vector_reward_key=.* collides with groups"),
        ({"x": {"step": 1.0}, "episode_x": {"final": 1.0}}, {}, r"reward group 'episode_x' is written beside 'x'"),
    ],
)
def test_key_collisions_of_the_group_entries_are_refused(groups: dict, kwargs: dict, match: str) -> None:
    task = RewardGroupsTask(CASES[COMPOSED](), groups)
    with pytest.raises(ValueError, match=match):
        TaskTransform(task, **kwargs)


# ---------------------------------------------------------------------------------------------- no cost when unused
def _spy(task: Task) -> list[int]:
    """Count the calls of ``_reward_groups`` on every task of the tree (an instance attribute shadows the method)."""
    calls: list[int] = []
    for module in task.modules():
        if isinstance(module, Task):
            method = module._reward_groups

            def counted(*args, method=method, **kwargs):
                calls.append(1)
                return method(*args, **kwargs)

            module.__dict__["_reward_groups"] = counted
    return calls


@pytest.mark.parametrize("grouped", [False, True], ids=["plain", "grouped"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_a_tree_without_groups_writes_no_group_entry_and_makes_no_group_call(name: str, grouped: bool) -> None:
    task = (_grouped(name, None).task if grouped else CASES[name]()).double()
    assert task.facts.has_groups == grouped and bool(task.group_names) == grouped
    kinds = {row.kind for row in TaskTransform(task).entries.rows}
    assert bool({"group", "groups"} & kinds) == grouped
    calls = _spy(task)
    draws = random_transitions(task, torch.Generator().manual_seed(1), 2, batch=3)
    memory = task.reset(draws["states"][0])
    for t in range(2):
        out = task.transition(
            draws["states"][t], draws["actions"][t], draws["states"][t + 1], memory, draws["remaining"][t],
            terminated=draws["terminated"][t], truncated=draws["truncated"][t],
        )  # fmt: skip
        memory = out.memory
        assert (out.groups != {}) == grouped
    assert bool(calls) == grouped  # the spy sees the calls of a grouped tree, and none of a plain one
