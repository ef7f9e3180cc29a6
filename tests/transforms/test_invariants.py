"""Every feature holds in every layout: one invariant suite over the combinations users build.

Features (``feature_envs.FEATURES``): a plain task without terms, named terms with a final reward, shaping, a
GoalCommand, a Curriculum, DifficultyLevels, constraints, named end conditions, per-env physics drawn by a
DomainRandomization (at resets under a Curriculum, at intervals under DifficultyLevels) and reward groups (float32
groups over a float64 state; groups whose coefficients a Curriculum ramps). Layouts: ``env.rollout``
``[B, T]``, a Collector's batch ``[B, T]``, the same flattened to ``[N]`` (grouped by trajectory ids),
``split_trajs`` (padded rows with a mask), a replay-buffer sample (random frames of a flat batch), and data
collected through a ``ParallelEnv`` or by a ``MultiSyncCollector`` (worker processes). Invariants:

- offline == online: the TaskTransform of a freshly built env of the same configuration (its buffers at their
  initial values, so a schedule's values must come from the data) re-judges the stored transitions and writes
  exactly what the online step wrote: reward, flags, breakdown, costs, end conditions and the reward groups (the
  vector reward and one entry per group);
- statistics == an independent count: ``episode_statistics`` on every layout equals a plain loop over the frames
  of the time-major collection, written here (episodes, outcome rates, lengths, returns per entry, costs, end
  conditions, the group returns, the drawn physics episodes ended with, the schedule and the levels at the end of
  the batch);
- save -> load continues, and a checkpoint of another configuration (batch size, schedule, level table, goal
  space, reward groups) is refused.

A defect that holds for one layout only (padding read as a frame, today's buffers used offline, the first
episode of a row taken as complete) fails here.
"""

from __future__ import annotations

import functools
import io
import math
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.collectors.utils import split_trajectories
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer, SamplerWithoutReplacement
from torchrl.envs import ParallelEnv

import feature_envs
from feature_envs import FEATURES, task_transform
from resume_env import equal_batches
from torchtasks.envs import PendulumEnv, PointMassEnv, swing_up_task
from torchtasks.rewards import VelocityReward
from torchtasks.spaces import Box
from torchtasks.stats import episode_statistics
from torchtasks.tasks import RewardGroupsTask
from torchtasks.transforms import (
    Curriculum,
    DifficultyLevels,
    DomainRandomization,
    GoalCommand,
    TaskTransform,
    collector_state,
    linear,
    load_collector_state,
    staged,
)

BATCH = 6
STEPS = 20  # frames per env and batch: episodes of up to MAX_STEPS start before the batch and run past it
SEED = 3


# ------------------------------------------------------------------------------------------------ layouts
def _collector(make: Callable, policy, workers: int = 0) -> Collector | MultiSyncCollector:
    kwargs = {"frames_per_batch": BATCH * STEPS, "total_frames": -1}
    if workers:
        return MultiSyncCollector([make] * workers, policy, **kwargs)
    return Collector(make(), policy, auto_register_policy_transforms=False, **kwargs)


def _time_major(batch: TensorDictBase) -> TensorDictBase:
    """A batch as rows of envs, time last ``[B, T]`` (a ParallelEnv's is ``[workers, b, T]``)."""
    return batch if batch.batch_dims == 2 else batch.reshape(-1, STEPS)


def _second_batch(collector) -> TensorDictBase:
    """The second batch of a run (its rows start inside episodes), time-major ``[B, T]``."""
    try:
        collector.set_seed(SEED)
        batches = iter(collector)
        next(batches)
        batch = next(batches).clone()
    finally:
        collector.shutdown()
    return _time_major(batch)


# The in-process data of a feature do not depend on the test (seeded envs, commands and draws, deterministic
# policies: checked equal under different global seeds), so each test process makes them once per feature and
# every layout and check gets a copy: 12 rollouts and 12 collections instead of 12 + 84.
@functools.cache
def _rollout(name: str) -> TensorDictBase:
    feature = FEATURES[name]
    env = feature.make_env(BATCH, SEED)
    return env.rollout(STEPS, feature.make_policy(), break_when_any_done=False)


@functools.cache
def _collected(name: str) -> TensorDictBase:
    feature = FEATURES[name]
    return _second_batch(_collector(functools.partial(feature.make_env, BATCH, SEED), feature.make_policy()))


def rollout(name: str) -> TensorDictBase:
    """``env.rollout`` of the feature's env and policy, ``[B, T]`` (a copy of this process's one rollout)."""
    return _rollout(name).clone()


def collected(name: str) -> TensorDictBase:
    """The second batch of a Collector over the feature's env, ``[B, T]`` (a copy of this process's one batch)."""
    return _collected(name).clone()


def flat(data: TensorDictBase) -> TensorDictBase:
    return data.reshape(-1)


def padded(data: TensorDictBase) -> TensorDictBase:
    """``split_trajs=True``: one trajectory per row, padded with zeros, ``("collector", "mask")`` marks frames."""
    return split_trajectories(data.clone())


def sampled(data: TensorDictBase, *, replacement: bool = True) -> TensorDictBase:
    """A replay buffer's sample: half of the frames, drawn at random (by default with replacement, as TorchRL's)."""
    frames = data.reshape(-1)
    sampler = RandomSampler() if replacement else SamplerWithoutReplacement()
    buffer = ReplayBuffer(storage=LazyTensorStorage(frames.numel()), sampler=sampler, batch_size=frames.numel() // 2)
    buffer.extend(frames)
    torch.manual_seed(SEED)
    return buffer.sample()


LAYOUTS: dict[str, Callable[[TensorDictBase], TensorDictBase]] = {
    "time_major": lambda data: data,
    "flat": flat,
    "split_trajs": padded,
    "replay_sample": sampled,
}


# ------------------------------------------------------------------------------------------------ offline == online
def _judged_keys(data: TensorDictBase, name: str) -> list:
    transform = task_transform(FEATURES[name].make_env(BATCH, SEED))
    keys = [transform.reward_key, transform.success_key, transform.failure_key, "terminated", "done"]
    keys += transform.term_keys + transform.cost_keys + list(transform._ended_by_keys)
    keys += transform.entries.keys(argument="vector_reward_key") + transform.entries.keys(argument="groups_key")
    return [key for key in keys if ("next", *((key,) if isinstance(key, str) else key)) in data.keys(True, True)]


def _offline_matches_online(name: str, data: TensorDictBase) -> None:
    env = FEATURES[name].make_env(BATCH, SEED)
    env.reset()  # a fresh env of the same configuration: set up, its run state at its start
    transform = task_transform(env)
    mask = data.get(("collector", "mask"), None)
    keys = _judged_keys(data, name)
    stored = data.clone()
    recomputed = data.clone()
    transform.relabel(recomputed)
    for key in keys:
        expected, actual = stored["next", key], recomputed["next", key]
        if mask is not None:
            expected, actual = expected[mask], actual[mask]
        assert torch.equal(actual, expected), (
            f"{name}: {key!r} recomputed offline differs from the online step: max |diff| "
            f"{(actual.double() - expected.double()).abs().max().item()}"
        )


@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("name", list(FEATURES))
def test_offline_recomputation_equals_the_online_step(name: str, layout: str):
    data = collected(name) if layout != "time_major" else rollout(name)
    _offline_matches_online(name, LAYOUTS[layout](data))


# ------------------------------------------------------------------------------------------------ statistics == count
def count_statistics(data: TensorDictBase) -> dict[str, float]:
    """The statistics of a time-major ``[B, T]`` batch counted frame by frame, as the docs define them.

    An episode ends at a done frame; its length is its ``step_count`` there; it is complete when all those frames
    are in its row; returns sum the reward (and each entry of the breakdown and the costs) over its frames. The
    schedule and the levels are read at the last frame of every row (the end of the batch) and averaged over rows.
    The groups of a vector reward are summed like the terms, one entry per group (``group_return_mean/<group>``).
    The steps with a push are summed like the terms (``push_steps_mean/<kind>``); the biases of the noisy entries at
    the episodes' last frames give their root mean square (``observation_bias_rms/<entry>``).
    """
    nxt = data["next"]
    rows, steps = data.batch_size
    entries = {"return_mean": nxt["reward"]}
    for group, prefix in (
        ("task_reward", "return_mean/"),
        ("task_cost", "cost_mean/"),
        ("reward_groups", "group_return_mean/"),
    ):
        if group in nxt.keys():
            for leaf in nxt[group].keys():
                others = set(nxt[group].keys())
                if not (leaf.startswith("episode_") and leaf[len("episode_") :] in others):
                    entries[prefix + leaf] = nxt[group, leaf]
    for kind in ("velocity", "wrench"):  # the steps with a push, summed per episode
        if f"push_{kind}" in nxt.keys():
            entries["push_steps_mean/" + kind] = (nxt[f"push_{kind}"] != 0).any(-1)
    ended_by = list(nxt["ended_by"].keys()) if "ended_by" in nxt.keys() else []
    ends, complete_sums = [], {stat: [] for stat in entries}
    for row in range(rows):
        for t in range(steps):
            if not bool(nxt["done"][row, t]):
                continue
            length = int(nxt["step_count"][row, t])
            ends.append((row, t, length))
            if t - length + 1 >= 0:  # every frame of the episode is in the row
                for stat, value in entries.items():
                    complete_sums[stat].append(sum(float(value[row, s]) for s in range(t - length + 1, t + 1)))
    stats = {"episodes": float(len(ends)), "complete_episodes": float(len(complete_sums["return_mean"]))}

    def rate(flag) -> float:
        return sum(bool(flag[row, t]) for row, t, _ in ends) / len(ends)

    if ends:
        # a task writes the outcome flags it defines only (no "success" for a tree that cannot succeed): an outcome
        # without a flag has no rate and never happens
        task_end = torch.zeros_like(nxt["done"])
        for outcome in ("success", "failure"):
            if outcome in nxt.keys():
                stats[f"{outcome}_rate"] = rate(nxt[outcome])
                task_end = task_end | nxt[outcome]
        stats["timeout_rate"] = rate(nxt["truncated"] & ~nxt["terminated"] & ~task_end)
        stats["env_termination_rate"] = rate(nxt["terminated"] & ~task_end)
        stats["episode_length_mean"] = sum(length for _, _, length in ends) / len(ends)
        for name in ended_by:
            stats[f"ended_by/{name}"] = rate(nxt["ended_by", name])
        if complete_sums["return_mean"]:
            for stat, sums in complete_sums.items():
                stats[stat] = sum(sums) / len(sums)
        for name in nxt["domain"].keys() if "domain" in nxt.keys() else []:  # the physics each episode ended with
            values = [nxt["domain", name][row, t].reshape(-1) for row, t, _ in ends]
            for i in range(len(values[0])):
                key = f"domain/{name}" if len(values[0]) == 1 else f"domain/{name}/{i}"
                stats[key] = sum(float(value[i]) for value in values) / len(ends)
        biases = [key for key in nxt.keys() if key.startswith("observation_bias_")]  # the biases episodes ended with
        for key in biases:
            squares = [float(v) ** 2 for row, t, _ in ends for v in nxt[key][row, t].reshape(-1)]
            name = key.removeprefix("observation_bias_")
            stats["observation_bias_rms/" + name] = math.sqrt(sum(squares) / len(squares))
    if "curriculum" in nxt.keys():
        for name in nxt["curriculum"].keys():
            last = nxt["curriculum", name][:, -1].reshape(rows, -1)
            if name == "level":
                levels = [int(level) for level in last[:, 0]]
                stats["curriculum/level"] = sum(levels) / rows
                for k in range(max(levels) + 1):
                    stats[f"curriculum/level_fraction/{k}"] = levels.count(k) / rows
            elif last.shape[1] == 1:
                stats[f"curriculum/{name}"] = sum(float(v) for v in last[:, 0]) / rows
            else:
                for i in range(last.shape[1]):
                    stats[f"curriculum/{name}/{i}"] = sum(float(v) for v in last[:, i]) / rows
    return stats


def _statistics_match(actual: dict[str, float], expected: dict[str, float], what: str) -> None:
    assert set(actual) == set(expected), f"{what}: keys differ: {sorted(set(actual) ^ set(expected))}"
    for key, value in expected.items():
        assert math.isclose(actual[key], value, rel_tol=1e-9, abs_tol=1e-9), (
            f"{what}: {key} = {actual[key]}, counted {value}"
        )


STATISTICS_LAYOUTS = ["time_major", "flat", "split_trajs", "shuffled"]


def _statistics_layout(data: TensorDictBase, layout: str) -> TensorDictBase:
    if layout == "shuffled":  # a replay buffer holding the whole batch, frames in random order
        frames = data.reshape(-1)
        return frames[torch.randperm(frames.numel(), generator=torch.Generator().manual_seed(SEED))]
    return LAYOUTS[layout](data)


def _statistics_hold(name: str, data: TensorDictBase, layout: str) -> None:
    """``episode_statistics`` of ``data`` in ``layout`` equals the count; levels alone have no order in a layout that
    is not time-major (no frame count says which frame is an env's latest): refused there, with a way out."""
    expected = count_statistics(data)
    assert expected["episodes"] > 0 and expected["complete_episodes"] > 0
    arranged = _statistics_layout(data, layout)
    schedule = set(data["next", "curriculum"].keys()) if "curriculum" in data["next"].keys() else set()
    if "level" in schedule and "frames" not in schedule and layout != "time_major":
        with pytest.raises(ValueError, match="curriculum_key=None"):
            episode_statistics(arranged)
        expected = {k: v for k, v in expected.items() if not k.startswith("curriculum/")}
        _statistics_match(episode_statistics(arranged, curriculum_key=None), expected, f"{name}, {layout}")
        return
    _statistics_match(episode_statistics(arranged), expected, f"{name}, {layout}")


@pytest.mark.parametrize("layout", STATISTICS_LAYOUTS)
@pytest.mark.parametrize("name", list(FEATURES))
def test_statistics_equal_an_independent_count(name: str, layout: str):
    _statistics_hold(name, collected(name), layout)


def test_a_replay_sample_counts_the_episodes_it_holds_whole():
    """A random sample holds some episodes whole: their returns are the full batch's for the same episodes."""
    data = collected("constraints")
    sample = sampled(data, replacement=False)  # a frame held twice is refused (it would fake a complete episode)
    stats = episode_statistics(sample)
    ids = sample["collector", "traj_ids"]
    assert stats["episodes"] == float(sample["next", "done"].sum())
    whole = [
        int(i)
        for i in ids.unique()
        if int((ids == i).sum()) == int(sample["next", "step_count"][(ids == i) & sample["next", "done"][..., 0]].sum())
    ]
    assert stats["complete_episodes"] == float(len(whole))


# ---------------------------------------------------------------------------------------------- save -> load continues
def _single_collector(name: str) -> Collector:
    feature = FEATURES[name]
    return _collector(functools.partial(feature.make_env, BATCH, SEED), feature.make_policy())


def _parallel_collector(name: str) -> Collector:
    feature = FEATURES[name]
    make = functools.partial(feature.make_env, BATCH // 2, SEED)
    return _collector(functools.partial(ParallelEnv, 2, make, use_buffers=False), feature.make_policy())


def _multi_sync_collector(name: str) -> MultiSyncCollector:
    feature = FEATURES[name]
    return _collector(functools.partial(feature.make_env, BATCH // 2, SEED), feature.make_policy(), workers=2)


def _saved(state: dict) -> dict:
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def _resume_continues(
    name: str, make: Callable[[str], Collector | MultiSyncCollector], *, ids: bool = True
) -> TensorDictBase:
    """Two batches, a checkpoint, two more: a fresh collector loading the checkpoint collects those two again.

    Returns the second batch, time-major ``[B, T]`` (what ``_second_batch`` of a fresh collector gives).
    """
    running = make(name)
    try:
        running.set_seed(SEED)
        batches = iter(running)
        next(batches)
        second_batch = _time_major(next(batches).clone())
        checkpoint = _saved(collector_state(running))
        expected = [next(batches).clone() for _ in range(2)]
    finally:
        running.shutdown()
    resumed = make(name)
    try:
        load_collector_state(resumed, checkpoint)
        batches = iter(resumed)
        actual = [next(batches).clone() for _ in range(2)]
    finally:
        resumed.shutdown()
    for i, (first, second) in enumerate(zip(expected, actual, strict=True)):
        assert equal_batches(first, second) == [], f"{name}: batch {i} after the resume differs"
        if ids:
            assert torch.equal(first["collector", "traj_ids"], second["collector", "traj_ids"])
    return second_batch


@pytest.mark.parametrize("name", list(FEATURES))
def test_a_resume_continues_the_saved_run(name: str):
    _resume_continues(name, _single_collector)


# ------------------------------------------------------------------------------------------------ worker processes
PROCESS_FEATURES = ["curriculum", "levels", "constraints", "domain", "groups_scheduled"]


@pytest.mark.multiprocess
@pytest.mark.xdist_group("multiprocess")
@pytest.mark.parametrize("layout", ["parallel_env", "multi_sync"])
@pytest.mark.parametrize("name", PROCESS_FEATURES)
def test_worker_processes_keep_the_invariants_and_resume(name: str, layout: str, fork_start_method):
    """The data of worker processes: offline == online and statistics == the count, on the second batch of the
    run that is then saved and resumed (one run of the worker processes for all three invariants)."""
    if layout == "parallel_env":
        data = _resume_continues(name, _parallel_collector)
    else:  # a MultiSyncCollector's workers draw new trajectory ids from one shared counter in a racy order
        data = _resume_continues(name, _multi_sync_collector, ids=False)
    _offline_matches_online(name, data)
    _offline_matches_online(name, flat(data))
    for statistics_layout in STATISTICS_LAYOUTS:
        _statistics_hold(name, data, statistics_layout)


# ------------------------------------------------------------------------------------------------ other configurations
def _other_curriculum(batch: int, seed: int):
    """The curriculum feature with another kind of schedule for one target (the data carry the same entries)."""
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    schedules = {feature_envs.SCHEDULED: linear(0.0, 1.0, 0, 200), "success_value": staged({0: 10.0, 100: 100.0})}
    return feature_envs._finish(PendulumEnv(batch_size=[batch], seed=seed), task, Curriculum(schedules))


def _other_levels(batch: int, seed: int):
    """The levels feature with two levels instead of three."""
    tables = {"command.low": [[-0.1, -0.1], [-0.5, -0.5]], "command.high": [[0.1, 0.1], [0.5, 0.5]]}
    command = GoalCommand(Box([-0.5, -0.5], [0.5, 0.5]), seed=seed)
    task = TaskTransform(feature_envs._masked_reach(), goal_key="goal")
    return feature_envs._finish(PointMassEnv(batch_size=[batch], seed=seed), task, DifficultyLevels(2, tables), command)


def _other_goal_command(batch: int, seed: int):
    """The goal feature with a narrower goal space: the saved range leaves it."""
    command = GoalCommand(Box([-0.3, -0.3], [0.3, 0.3]), resample_steps=(3, 5), seed=seed)
    task = TaskTransform(feature_envs._masked_reach(), goal_key="goal")
    return feature_envs._finish(PointMassEnv(batch_size=[batch], seed=seed), task, command)


def _other_domain(batch: int, seed: int):
    """The domain feature drawing every 4 steps instead of at every reset."""
    task = TaskTransform(swing_up_task(success_threshold=0.6))
    curriculum = Curriculum({"domain.mass.halfspan": linear(0.0, 0.5, 0, 200)})
    randomization = DomainRandomization(feature_envs._pendulum_params(), when="interval", every=4, seed=seed)
    return feature_envs._finish(PendulumEnv(batch_size=[batch], seed=seed), task, randomization, curriculum)


def _other_groups(batch: int, seed: int):
    """The groups feature with one source fewer: coefficients of another shape."""
    groups = {**feature_envs.GROUPS, "energy": {"effort": 1000.0, "speed": -0.25}}
    task = RewardGroupsTask(
        swing_up_task(success_threshold=0.6), groups, terms={"speed": VelocityReward(1.0, index=1)}, dtype=torch.float32
    )
    env = PendulumEnv(batch_size=[batch], seed=seed, dtype=torch.float64)
    return feature_envs._finish(env, TaskTransform(task))


def _other_group_sources(batch: int, seed: int):
    """The groups_scheduled feature with the same groups and as many coefficients, read from other sources (the
    saved coefficients would be cross-loaded by position)."""
    groups = {"tracking": {"track": 1.0, "step": 0.5}, "energy": {"effort": 1000.0, "speed": -0.25, "final": 0.125}}
    task = RewardGroupsTask(swing_up_task(success_threshold=0.6), groups, terms={"speed": VelocityReward(1.0, index=1)})
    curriculum = Curriculum(feature_envs.GROUP_RAMPS)
    return feature_envs._finish(PendulumEnv(batch_size=[batch], seed=seed), TaskTransform(task), curriculum)


OTHER_CONFIGURATIONS = {
    "groups": (_other_groups, r"other reward groups: saved .*, here \{.*'energy': \['effort', 'speed'\]\}"),
    "groups_scheduled": (_other_group_sources, r"other reward groups: saved \{'tracking': \['track', 'final'\]"),
    "domain": (_other_domain, "when: saved 'reset', here 'interval'"),
    "curriculum": (_other_curriculum, "'success_value' is staged here, but the checkpoint holds a linear"),
    "levels": (_other_levels, r"shape \[2, 2\] here"),
    "goal_command": (_other_goal_command, "must lie in this command's goal space"),
}


@pytest.mark.parametrize("name", list(FEATURES))
def test_a_load_into_another_configuration_is_refused(name: str):
    """Another batch size for every feature; another schedule, level table, goal space or reward groups where the
    feature has them."""
    running = _single_collector(name)
    try:
        running.set_seed(SEED)
        next(iter(running))
        checkpoint = _saved(collector_state(running))
    finally:
        running.shutdown()
    feature = FEATURES[name]
    variants = [(functools.partial(feature.make_env, BATCH + 2, SEED), "do not fit this collector")]
    if name in OTHER_CONFIGURATIONS:
        make, match = OTHER_CONFIGURATIONS[name]
        variants.append((functools.partial(make, BATCH, SEED), match))
    for make, match in variants:
        other = _collector(make, feature.make_policy())
        try:
            with pytest.raises(ValueError, match=match):
                load_collector_state(other, checkpoint)
        finally:
            other.shutdown()
