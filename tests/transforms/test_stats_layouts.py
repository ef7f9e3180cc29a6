"""episode_statistics gives the numbers of an independent count on every layout it documents, for every kind of task.

Configurations (:data:`CONFIGS`): a plain task without named terms or final reward (the README's first
task), compound terms with a final reward (``swing_up_task``), the same under a Curriculum with
DifficultyLevels, DifficultyLevels alone, and a ConstrainedTask with a cost limit. Layouts: ``env.rollout``
``[B, T]``, a Collector's batch ``[B, T]``, that batch flattened to ``[N]`` (in collection order and shuffled),
``split_trajs=True`` (padded ``[trajectories, max_len]`` with ``("collector", "mask")``, also flattened) and a
replay-buffer sample (flat, random order, part of the frames).

:func:`count_episodes` is the independent count: a Python loop over the frames (lists, no tensor code)
that groups them into episodes by trajectory id (or, without ids, by the done frames of each row), knows
an episode complete when its root step counts are exactly ``0 .. L-1``, and reads the schedule and the
levels at the latest frames (the last column of an unpadded ``[B, T]`` batch, else the frames with the
largest Curriculum frame count). Layouts of the same collection must also agree with each other, so the
padded layout is held to the values at the end of the unsplit batch.
"""

from __future__ import annotations

import functools
import math
from collections import defaultdict
from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.collectors.utils import split_trajectories
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers import SamplerWithoutReplacement
from torchrl.envs import Compose, StepCounter, TransformedEnv

from torchtasks.envs import PendulumEnv, swing_up_task
from torchtasks.rewards import QuadraticErrorReward, StateFunctionReward
from torchtasks.spaces import Box, EnvSpec
from torchtasks.stats import episode_statistics
from torchtasks.tasks import ConstrainedTask, Constraint, DesiredStateTask, proximity_succeeded
from torchtasks.transforms import Curriculum, DifficultyLevels, TaskTransform, linear

ENVS, MAX_STEPS = 4, 8
ROLLOUT_STEPS = 40
BATCH_STEPS, BATCHES = 20, 3  # Collector batches of [4, 20]: the later ones start in the middle of episodes
SAMPLE = 150  # frames of the replay-buffer sample, out of the 240 collected
SPEED_LIMIT = 3.0  # the ConstrainedTask's limit on the summed "fast" cost
MASK = ("collector", "mask")


def plain_task() -> DesiredStateTask:
    """One quadratic reward, no named terms, no final reward: success near upright, failure past ±0.9 rad."""
    success = functools.partial(proximity_succeeded, threshold=0.2, dims=0)
    spec = EnvSpec(Box([-0.9, -8.5], [0.9, 8.5]), 1)
    return DesiredStateTask(spec, [0.0, 0.0], QuadraticErrorReward([1.0, 0.1], [0.01]), success=success)


def constrained_task() -> ConstrainedTask:
    fast = StateFunctionReward(lambda state: (state[..., 1].abs() > 1.0).to(state.dtype), negate=False)
    return ConstrainedTask(plain_task(), {"fast": Constraint(fast, limit=SPEED_LIMIT)})


def schedules() -> Curriculum:
    return Curriculum(
        {
            "success_value": linear(0.0, 100.0, 0, 1000),  # scalar
            "wrapped_task.reward.rewards.track.Q": linear([1.0, 0.1], [3.0, 0.5], 0, 2000),  # [2]
        }
    )


#: name -> (task, extra transforms after the TaskTransform, episode_statistics keyword arguments)
CONFIGS: dict[str, tuple[Callable, Callable[[], list], dict]] = {
    "plain": (plain_task, list, {}),
    "terms_and_final": (functools.partial(swing_up_task, success_threshold=0.6), list, {}),
    "curriculum_and_levels": (
        functools.partial(swing_up_task, success_threshold=0.6),
        lambda: [schedules(), DifficultyLevels(3)],
        {},
    ),
    "levels": (plain_task, lambda: [DifficultyLevels(3, initial_level=1)], {}),
    "constrained": (constrained_task, list, {"cost_limits": {"fast": SPEED_LIMIT}}),
}


def make_env(config: str, seed: int = 0) -> TransformedEnv:
    task, extra, _ = CONFIGS[config]
    base = PendulumEnv(batch_size=[ENVS], init_angle=0.6, init_speed=1.5, seed=seed)
    return TransformedEnv(base, Compose(StepCounter(MAX_STEPS), TaskTransform(task()), *extra()))


def collect(config: str, *, split_trajs: bool = False) -> list[TensorDictBase]:
    threads = torch.get_num_threads()
    torch.manual_seed(1)  # the random actions
    collector = Collector(
        functools.partial(make_env, config, 1),
        None,
        frames_per_batch=ENVS * BATCH_STEPS,
        total_frames=ENVS * BATCH_STEPS * BATCHES,
        split_trajs=split_trajs,
    )
    try:
        return [batch.clone() for batch in collector]
    finally:
        collector.shutdown()
        torch.set_num_threads(threads)


@functools.cache
def rollout(config: str) -> TensorDictBase:
    torch.manual_seed(0)
    return make_env(config).rollout(ROLLOUT_STEPS, break_when_any_done=False)


@functools.cache
def batches(config: str) -> tuple[TensorDictBase, ...]:
    return tuple(collect(config))


# --------------------------------------------------------------------------------------------------
# The independent count
# --------------------------------------------------------------------------------------------------


def _frames(data: TensorDictBase) -> list[dict]:
    """Every frame of ``data`` (batch order, time last) as a dict of Python values: ``row`` (for ``[B, T]``
    data), ``valid``, the flags, step counts, rewards, terms, costs and scheduled values."""
    n = data.numel()

    def column(key, default=None):
        value = data.get(key, None)
        if value is None:
            return [default] * n
        return value.reshape(n, -1).tolist()

    def leaves(prefix):
        entries = data.get(prefix, None)
        if entries is None:
            return {}
        names = [(name,) if isinstance(name, str) else name for name in entries.keys(True, True)]
        return {"/".join(name): column((*prefix, *name)) for name in names if not name[-1].startswith("episode_")}

    columns = {
        "valid": column(MASK, [True]),
        "traj": column(("collector", "traj_ids")),
        "done": column(("next", "done")),
        "terminated": column(("next", "terminated")),
        "truncated": column(("next", "truncated")),
        "success": column(("next", "success")),
        "failure": column(("next", "failure")),
        "steps_before": column("step_count"),
        "steps_after": column(("next", "step_count")),
        "reward": column(("next", "reward")),
    }
    terms, costs = leaves(("next", "task_reward")), leaves(("next", "task_cost"))
    schedule = leaves(("next", "curriculum"))
    time = data.shape[-1] if data.ndim == 2 else None
    frames = []
    for i in range(n):
        frame = {name: values[i][0] if values[i] is not None else None for name, values in columns.items()}
        frame["row"] = None if time is None else i // time
        frame["last_column"] = time is not None and i % time == time - 1
        frame["terms"] = {name: values[i][0] for name, values in terms.items()}
        frame["costs"] = {name: values[i][0] for name, values in costs.items()}
        frame["schedule"] = {name: values[i] for name, values in schedule.items()}
        frames.append(frame)
    return frames


def count_episodes(data: TensorDictBase, *, cost_limits: dict[str, float] | None = None) -> dict[str, float]:
    """The statistics of ``data`` counted frame by frame (see the module docstring)."""
    frames = [frame for frame in _frames(data) if frame["valid"]]
    episodes: dict[object, list[dict]] = defaultdict(list)
    done_in_row: dict[int, int] = defaultdict(int)
    for frame in frames:  # batch order: the frames of a row in time order
        key = frame["traj"] if frame["traj"] is not None else (frame["row"], done_in_row[frame["row"]])
        episodes[key].append(frame)
        if frame["traj"] is None and frame["done"]:
            done_in_row[frame["row"]] += 1
    ended = []
    for members in episodes.values():
        last = [frame for frame in members if frame["done"]]
        if not last:
            continue
        (last,) = last
        length = last["steps_after"]
        ended.append(
            {
                "last": last,
                "length": length,
                "complete": sorted(frame["steps_before"] for frame in members) == list(range(length)),
                "return": sum(frame["reward"] for frame in members),
                "terms": {name: sum(frame["terms"][name] for frame in members) for name in last["terms"]},
                "costs": {name: sum(frame["costs"][name] for frame in members) for name in last["costs"]},
            }
        )

    def mean(values):
        values = [float(value) for value in values]
        return sum(values) / len(values)

    complete = [episode for episode in ended if episode["complete"]]
    stats = {"episodes": float(len(ended)), "complete_episodes": float(len(complete))}
    if ended:
        last = [episode["last"] for episode in ended]
        stats["success_rate"] = mean(frame["success"] for frame in last)
        stats["failure_rate"] = mean(frame["failure"] for frame in last)
        by_env = [frame for frame in last if not (frame["success"] or frame["failure"])]  # neither task flag
        stats["timeout_rate"] = sum(f["truncated"] and not f["terminated"] for f in by_env) / len(last)
        stats["env_termination_rate"] = sum(bool(f["terminated"]) for f in by_env) / len(last)
        stats["episode_length_mean"] = mean(episode["length"] for episode in ended)
    if complete:
        stats["return_mean"] = mean(episode["return"] for episode in complete)
        for name in complete[0]["terms"]:
            stats[f"return_mean/{name}"] = mean(episode["terms"][name] for episode in complete)
        for name in complete[0]["costs"]:
            stats[f"cost_mean/{name}"] = mean(episode["costs"][name] for episode in complete)
            if cost_limits and name in cost_limits:
                stats[f"cost_violation_rate/{name}"] = mean(
                    episode["costs"][name] > cost_limits[name] for episode in complete
                )
    stats.update(latest_schedule(data, frames))
    return stats


def latest_schedule(data: TensorDictBase, frames: list[dict]) -> dict[str, float]:
    """The scheduled values and levels at the latest frames: the last column of an unpadded [B, T] batch, else the
    valid frames with the largest Curriculum frame count."""
    if not frames or not frames[0]["schedule"]:
        return {}
    if data.ndim == 2 and MASK not in data.keys(True):
        latest = [frame for frame in frames if frame["last_column"]]
    else:
        newest = max(frame["schedule"]["frames"][0] for frame in frames)  # KeyError without a frame count
        latest = [frame for frame in frames if frame["schedule"]["frames"][0] == newest]
    stats = {}
    for name in frames[0]["schedule"]:
        values = [frame["schedule"][name] for frame in latest]
        if name == "level":
            levels = [value[0] for value in values]
            stats["curriculum/level"] = sum(levels) / len(levels)
            for k in range(max(levels) + 1):
                stats[f"curriculum/level_fraction/{k}"] = levels.count(k) / len(levels)
            continue
        entries = [sum(value[i] for value in values) / len(values) for i in range(len(values[0]))]
        if len(entries) == 1:
            stats[f"curriculum/{name}"] = entries[0]
        else:
            stats.update((f"curriculum/{name}/{i}", entry) for i, entry in enumerate(entries))
    return stats


def assert_same(got: dict[str, float], want: dict[str, float]) -> None:
    assert set(got) == set(want), f"keys {sorted(got)} != {sorted(want)}"
    assert all(type(value) is float and math.isfinite(value) for value in got.values()), got
    assert got == pytest.approx(want, rel=1e-9, abs=1e-9)


def statistics(config: str, data: TensorDictBase, **kwargs) -> dict[str, float]:
    return episode_statistics(data, **CONFIGS[config][2], **kwargs)


def reference(config: str, data: TensorDictBase) -> dict[str, float]:
    return count_episodes(data, cost_limits=CONFIGS[config][2].get("cost_limits"))


def split(batch: TensorDictBase) -> TensorDictBase:
    """A Collector's split_trajs=True layout of ``batch`` (the function the Collector applies to its batches)."""
    return split_trajectories(batch, prefix="collector")


def without_schedule(data: TensorDictBase) -> TensorDictBase:
    return data.exclude("curriculum", ("next", "curriculum"))


# --------------------------------------------------------------------------------------------------
# The data exercises what the statistics count
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("config", list(CONFIGS))
def test_the_data_holds_every_ending_and_partial_episodes(config: str) -> None:
    data = rollout(config)
    nxt = data["next"]
    assert nxt["done"].sum() >= 10 and nxt["success"].any()
    assert (nxt["truncated"] & ~nxt["terminated"]).any()
    if config not in ("terms_and_final", "curriculum_and_levels"):  # swing_up_task cannot fail
        assert nxt["failure"].any()
    for batch in batches(config)[1:]:  # episodes that started before the batch, and padding when split
        stats = statistics(config, batch, curriculum_key=None)
        assert stats["complete_episodes"] < stats["episodes"]
        assert not split(batch)[MASK].all()
    has_terms = ("next", "task_reward") in data.keys(True)
    assert has_terms == (config in ("terms_and_final", "curriculum_and_levels"))
    if "levels" in config:
        assert data["next", "curriculum", "level"].unique().numel() >= 2


# --------------------------------------------------------------------------------------------------
# Every layout against the independent count
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("config", list(CONFIGS))
def test_rollout(config: str) -> None:
    """env.rollout [B, T]: every episode starts in the data; the defaults work on whatever the task wrote."""
    data = rollout(config)
    stats = statistics(config, data)
    assert_same(stats, reference(config, data))
    assert stats["episodes"] == stats["complete_episodes"]


@pytest.mark.parametrize("config", list(CONFIGS))
def test_collector_batches(config: str) -> None:
    """A Collector's [B, T] batches, flattened in collection order and shuffled: the same numbers."""
    generator = torch.Generator().manual_seed(0)
    for batch in batches(config):
        stats = statistics(config, batch)
        assert_same(stats, reference(config, batch))
        flat = batch.reshape(-1)
        shuffled = flat[torch.randperm(flat.numel(), generator=generator)]
        for layout in (flat, shuffled):
            if config == "levels":  # nothing orders the frames of a flat batch without a Curriculum's count
                with pytest.raises(ValueError, match="frame count"):
                    statistics(config, layout)
                layout = without_schedule(layout)
                stats = statistics(config, without_schedule(batch))
            assert_same(statistics(config, layout), reference(config, layout))
            assert_same(statistics(config, layout), stats)


@pytest.mark.parametrize("config", list(CONFIGS))
def test_split_trajectories(config: str) -> None:
    """split_trajs=True: padded trajectories with a mask give the unsplit batch's numbers (padding never counts)."""
    for index, batch in enumerate(batches(config), start=1):
        padded = split(batch)
        assert padded.shape[0] > ENVS  # several trajectories of one env in the batch
        unsplit = statistics(config, batch)
        if "curriculum" in config:  # the schedule at the end of the batch, not at a row's padding
            assert unsplit["curriculum/frames"] == ENVS * BATCH_STEPS * index
        for layout in (padded, padded.reshape(-1)):
            if config == "levels":  # rows are trajectories: which one holds an env's last frame is unknown
                with pytest.raises(ValueError, match=r"padded batch|flat batch"):
                    statistics(config, layout)
                layout, unsplit = without_schedule(layout), statistics(config, without_schedule(batch))
            stats = statistics(config, layout)
            assert_same(stats, reference(config, layout))
            assert_same(stats, unsplit)


@pytest.mark.parametrize("config", ["curriculum_and_levels", "constrained"])
def test_padding_is_never_read(config: str) -> None:
    """Padded frames filled with values that would change every statistic, and a row of padding only: no change."""
    for batch in batches(config):
        padded = split(batch)
        want = statistics(config, padded)
        junk = padded.clone()
        pad = ~junk[MASK]
        for key in junk.keys(True, True):
            if key[0] == "collector":
                continue
            value = junk.get(key)
            if value.dtype == torch.bool:
                value[pad] = True
            elif value.is_floating_point():
                value[pad] = 1e3
            else:
                value[pad] = 10**6 if "frames" in key else 1  # the largest frame count; level 1; step count 1
        extra = junk[-1:].clone()
        extra[MASK] = torch.zeros_like(extra[MASK])
        junk = torch.cat([junk, extra])
        assert junk["next", "done"].sum() > padded["next", "done"].sum()
        assert_same(statistics(config, junk), want)
        assert_same(statistics(config, junk.reshape(-1)), want)


@pytest.mark.filterwarnings("ignore:split_trajs=True produces")
def test_a_split_trajs_collector_writes_the_layout_tested() -> None:
    """A Collector with split_trajs=True returns split_trajectories(batch, prefix="collector") of its batch."""
    config = "curriculum_and_levels"
    padded = collect(config, split_trajs=True)
    assert len(padded) == BATCHES
    for got, batch in zip(padded, batches(config), strict=True):
        want = split(batch)
        assert got.shape == want.shape and MASK in got.keys(True)
        assert (got == want).all()
        assert_same(statistics(config, got), statistics(config, batch))


@pytest.mark.parametrize("config", list(CONFIGS))
def test_replay_buffer_sample(config: str) -> None:
    """A sample of a replay buffer: flat, random order, part of the frames; the episodes whose frames it holds."""
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(ENVS * BATCH_STEPS * BATCHES),
        sampler=SamplerWithoutReplacement(),
        batch_size=SAMPLE,
    )
    for batch in batches(config):
        buffer.extend(batch.reshape(-1))
    torch.manual_seed(3)
    sample = buffer.sample()
    assert sample.shape == (SAMPLE,)
    if config == "levels":
        with pytest.raises(ValueError, match="frame count"):
            statistics(config, sample)
        sample = without_schedule(sample)
    stats = statistics(config, sample)
    assert_same(stats, reference(config, sample))
    assert 0 < stats["complete_episodes"] < stats["episodes"]  # the sample misses frames of some ended episodes
    # a frame held twice (a sample drawn with replacement) would be counted twice: refused
    middle = sample[~sample["next", "done"][:, 0]][:1]
    with pytest.raises(ValueError, match="holds some frame twice"):
        statistics(config, torch.cat([sample, middle]))


# --------------------------------------------------------------------------------------------------
# The mask argument
# --------------------------------------------------------------------------------------------------


def test_mask_key_and_its_checks() -> None:
    config = "curriculum_and_levels"
    batch = batches(config)[1]
    padded = split(batch)
    stats = statistics(config, padded)
    # a mask under another key (split_trajectories(trajectory_key=...) writes it beside the ids)
    moved = padded.clone()
    moved["mask"] = moved.pop(MASK)
    assert_same(statistics(config, moved, mask_key="mask"), stats)
    # without the mask, a row's padding is read as its latest frame: the schedule of frame count 0
    unmasked = statistics(config, padded, mask_key=None)
    assert unmasked["curriculum/frames"] < stats["curriculum/frames"]
    wrong = padded.clone()
    wrong[MASK] = wrong[MASK].long()
    with pytest.raises(TypeError, match=r"mask_key=\('collector', 'mask'\) must hold a bool mask"):
        statistics(config, wrong)
    holey = padded.clone()
    holey[MASK][0, 0] = False
    assert holey[MASK][0, 1]
    with pytest.raises(ValueError, match="valid frame after padding"):
        statistics(config, holey)
