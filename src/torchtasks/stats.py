"""Episode statistics of collected data: success, failure and timeout rates, lengths and returns per reward term.

:func:`episode_statistics` reads what a :class:`~torchtasks.transforms.TaskTransform` wrote into the
data (the task's ``success`` and ``failure`` flags, the env's ``done``/``terminated``/``truncated``
flags, the reward and its breakdown) and summarises the episodes that end in a batch. It re-applies
no threshold and knows no env: the numbers are the task's own verdicts, counted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from torchtasks._checks import check_int
from torchtasks._torchrl import key_parts, keys_text, nested_key
from torchtasks.transforms.names import (
    BIAS_KEY,
    COST_TERMS_KEY,
    CURRICULUM_KEY,
    DOMAIN_KEY,
    DONE_KEY,
    ENDED_BY_KEY,
    EPISODE_SUM_PREFIX,
    FAILURE_KEY,
    FRAMES,
    GROUPS_KEY,
    LEVEL,
    PUSH_KEY,
    PUSH_RECORDS,
    REWARD_KEY,
    SUCCESS_KEY,
    TERMINATED_KEY,
    TERMS_KEY,
    TRUNCATED_KEY,
    record_entry,
)

__all__ = ["episode_statistics"]

#: where TorchRL collectors write the trajectory id of every frame
TRAJ_IDS_KEY = ("collector", "traj_ids")
#: where TorchRL's split_trajectories (a collector's ``split_trajs=True``) marks the valid frames of a padded batch
MASK_KEY = ("collector", "mask")
#: StepCounter's entry: steps since the env's last reset (0 at the reset, L after the L-th step)
STEP_COUNT_KEY = "step_count"
#: InitTracker's entry: True on the first frame of an episode
IS_INIT_KEY = "is_init"
#: prefix of the scheduled values in the returned dict
CURRICULUM_PREFIX = "curriculum/"


class _Frames:
    """The batch's entries as ``[F, ...]`` frames: time-major rows ``[E, T]`` flattened, or a flat ``[N]`` batch."""

    def __init__(self, batch: TensorDictBase, time_dim: int | None) -> None:
        self.batch = batch
        self.time_dim = time_dim  # None: flat batch of transitions
        shape = batch.batch_size
        if time_dim is None:
            self.rows, self.steps = 1, shape[0]
        else:
            self.steps = shape[time_dim]
            self.rows = shape.numel() // self.steps if self.steps else 0
        self.count = self.rows * self.steps

    def get(self, key: tuple[str, ...], *, where: str = "next") -> torch.Tensor | None:
        """The entry ``("next", *key)`` (``where="next"``) or ``key`` (``"root"``) as ``[F, *rest]``, or None."""
        value = self.batch.get(("next", *key) if where == "next" else key, None)
        if value is None:
            return None
        if isinstance(value, TensorDictBase):
            raise TypeError(f"episode_statistics: {key!r} holds a TensorDict, expected a tensor")
        value = value.detach()
        ndim = self.batch.batch_dims
        if self.time_dim is not None and self.time_dim != ndim - 1:
            value = value.movedim(self.time_dim, ndim - 1)
        return value.reshape(self.count, *value.shape[ndim:])

    def scalar(self, key: tuple[str, ...], name: str, *, where: str = "next") -> torch.Tensor | None:
        """One value per frame (``[*B]`` or ``[*B, 1]`` entries) as ``[F]``; None when missing."""
        value = self.get(key, where=where)
        if value is None:
            return None
        if value.shape[1:].numel() != 1:
            raise ValueError(
                f"episode_statistics: {name} {key!r} must hold one value per frame (shape [*B] or [*B, 1] for the "
                f"batch shape {list(self.batch.batch_size)}), got trailing shape {list(value.shape[1:])}; "
                "select one agent group or reward entry first"
            )
        return value.reshape(self.count)

    def flag(self, key: tuple[str, ...], name: str, *, where: str = "next") -> torch.Tensor | None:
        value = self.scalar(key, name, where=where)
        return None if value is None else value != 0


def _required(frames: _Frames, key: tuple[str, ...], name: str, *, flag: bool = False) -> torch.Tensor:
    value = frames.flag(key, name) if flag else frames.scalar(key, name)
    if value is None:
        raise KeyError(
            f"episode_statistics: {name}={key if len(key) > 1 else key[0]!r} is not in the data (looked under "
            f"'next'); available keys are {keys_text(frames.batch.keys(True, True))}. Pass the key the data uses, "
            "or None to skip the statistics that need it."
        )
    return value


def _named_entries(
    frames: _Frames, key: tuple[str, ...] | None, name: str, *, flag: bool = False
) -> dict[str, torch.Tensor]:
    """The entries under ``("next", *key)`` as ``{name joined by "/": [F] values}``, without RewardSum's running sums
    (``episode_<term>``); ``{}`` when ``key`` is None or the data has no such entry."""
    if key is None:
        return {}
    entries = frames.batch.get(("next", *key), None)
    if entries is None:
        return {}
    if not isinstance(entries, TensorDictBase):
        raise TypeError(
            f"episode_statistics: ('next', *{key!r}) must hold named entries (a TensorDict), got a "
            f"{type(entries).__name__}; pass the TaskTransform's {name}, or {name}=None"
        )
    names = [(part,) if isinstance(part, str) else tuple(part) for part in entries.keys(True, True)]
    leaf_names = {parts[-1] for parts in names}
    return {
        "/".join(parts): _required(frames, (*key, *parts), name, flag=flag)
        for parts in names
        if not (parts[-1].startswith(EPISODE_SUM_PREFIX) and parts[-1][len(EPISODE_SUM_PREFIX) :] in leaf_names)
    }


def _time_dim(batch: TensorDictBase, time_dim: int | None) -> int | None:
    """The time dim as a non-negative index, or None for a flat batch grouped by the collector's trajectory ids."""
    ndim = batch.batch_dims
    if ndim == 0:
        raise ValueError(
            "episode_statistics: the batch has no batch dims; expected [*envs, time] frames (env.rollout, a "
            "collector's batch) or a flat [N] batch with ('collector', 'traj_ids')"
        )
    if time_dim is None:
        if ndim == 1 and batch.get(TRAJ_IDS_KEY, None) is not None:
            return None
        return ndim - 1
    time_dim = check_int(time_dim, "episode_statistics: time_dim")
    if not -ndim <= time_dim < ndim:
        raise ValueError(
            f"episode_statistics: time_dim must be an int in [{-ndim}, {ndim - 1}] for the batch shape "
            f"{list(batch.batch_size)}, got {time_dim!r}"
        )
    return time_dim % ndim


def episode_statistics(
    batch: TensorDictBase,
    *,
    reward_key: NestedKey | None = REWARD_KEY,
    success_key: NestedKey | None = SUCCESS_KEY,
    failure_key: NestedKey | None = FAILURE_KEY,
    terms_key: NestedKey | None = TERMS_KEY,
    goal_key: NestedKey | None = None,
    achieved_goal_key: NestedKey | None = None,
    curriculum_key: NestedKey | None = CURRICULUM_KEY,
    domain_key: NestedKey | None = DOMAIN_KEY,
    bias_key: NestedKey | None = BIAS_KEY,
    push_key: NestedKey | None = PUSH_KEY,
    cost_terms_key: NestedKey | None = COST_TERMS_KEY,
    ended_by_key: NestedKey | None = ENDED_BY_KEY,
    groups_key: NestedKey | None = GROUPS_KEY,
    cost_limits: Mapping[str, float] | None = None,
    time_dim: int | None = None,
    mask_key: NestedKey | None = MASK_KEY,
) -> dict[str, float]:
    """Return statistics of the episodes that end in ``batch``: outcome rates, mean length and returns per term.

    The numbers are counted from the data as the task and the env wrote it: how an episode ended is
    read from the flags under ``"next"`` at its last frame (where ``("next", "done")`` is True), and
    returns are sums of ``("next", reward_key)`` and of every entry of the reward breakdown
    ``("next", terms_key)`` over the episode's frames. Nothing is recomputed or re-thresholded.

    **Layouts.** The same collection gives the same numbers in each of these:

    - ``[*envs, time]`` (``env.rollout(..., break_when_any_done=False)``, a ``Collector``'s batch): each
      row along ``time_dim`` (default: the last batch dim, TorchRL's convention) holds one env's
      consecutive frames, and the env resets after every ``done`` frame.
    - padded ``[trajectories, time]`` (a ``Collector``'s ``split_trajs=True`` batch, TorchRL's
      ``split_trajectories``): each row is one trajectory followed by padding, marked False in
      ``mask_key``. Padded frames are in no episode: never counted in ``episodes``, lengths, returns
      or rates, never read as a latest frame; a row of padding only contributes nothing.
    - flat ``[N]`` with ``("collector", "traj_ids")`` (``batch.reshape(-1)`` of a collector's batch, a
      replay-buffer sample): frames are grouped by trajectory id (one id per episode, frames in any
      order); padded frames (``mask_key``) are left out. A sample reports the episodes whose done
      frame it holds; one of them is complete when the sample holds all its frames. A frame held twice
      (a sample drawn with replacement) is a ``ValueError`` when the data has step counts (without
      them it cannot be told). Without trajectory ids a 1-D batch is one env's time series.

    **Episodes that started before the batch.** Every episode that ends in the batch is counted in
    ``episodes`` and in the outcome rates, so consecutive batches count each episode exactly once. Its
    length is ``("next", "step_count")`` at the last frame when the data has it (StepCounter in the env);
    its return is known only when all its frames are in the batch, so ``return_mean`` (and
    ``episode_length_mean`` without step counts) are means over the ``complete_episodes``: ended
    episodes whose start is in the batch. The start is known from the step count (frames in the batch
    equal the episode's length), from a ``done`` frame just before it in the same row, or from
    InitTracker's ``is_init``; without any of these the first episode of each row is not complete.
    In a padded or flat batch the done frame before an episode is in another row, or in no known
    place: there the start is known from the step count or ``is_init`` only.
    RewardSum's running sums are not used (and its ``episode_*`` entries are not taken for terms): the
    results are the same with and without it.

    **No ended episode.** A mean or rate over zero episodes is left out, never NaN or a made-up 0:
    with no ended episode the result is ``{"episodes": 0.0, "complete_episodes": 0.0}`` (and the
    scheduled values, which need no episode).

    Returned keys (plain floats, ready for ``logger.log_scalar(name, value, step)``):

    - ``episodes``: number of episodes that end in the batch; ``complete_episodes``: those whose frames
      are all in the batch.
    - ``success_rate``, ``failure_rate``: fraction of the ended episodes whose last frame has the
      task's success / failure flag; each only when the data holds that flag (a task that cannot succeed,
      e.g. a locomotion task, has no success flag and no ``success_rate``).
    - ``timeout_rate``: truncated without success, failure or termination; ``env_termination_rate``:
      terminated by the env itself, neither success nor failure (left out when ``success_key`` or
      ``failure_key`` is None). Left out when the data has neither ``terminated`` nor ``truncated``.
    - ``episode_length_mean``: transitions per episode.
    - ``return_mean`` and ``return_mean/<term>`` for every entry of the breakdown (TaskTransform writes
      ``step`` and ``final`` for a tree that pays a final reward and one per named reward term; nested
      names are joined with ``/``). Data without a breakdown (a task with neither, e.g. a
      :class:`~torchtasks.tasks.DesiredStateTask` with one reward) give ``return_mean`` only.
    - ``final_goal_distance_mean`` (with ``goal_key`` and ``achieved_goal_key``): the mean over the
      ended episodes of the L2 distance between the goal that judged the episode's last step and the
      goal achieved by it. The goal is read at the root of the last frame: the goal of step ``t``,
      the one the policy saw and the one ``TaskTransform(goal_key=...)`` passed to the task (under
      ``"next"`` is the goal of the step after, which a :class:`~torchtasks.transforms.GoalCommand`
      may already have redrawn: after a success with ``resample_on_success``, or when its timer ran
      out in that step). The achieved goal is read under ``"next"`` (that of ``s_{t+1}``, as
      ``TaskTransform(achieved_goal_key=...)`` writes it).
    - ``curriculum/frames`` and ``curriculum/<target>`` (when the data holds a
      :class:`~torchtasks.transforms.Curriculum`'s entries ``("next", curriculum_key, ...)``): the
      schedule at the end of the batch, read under ``"next"`` at the latest frame: the frame count and
      the values the step after the batch will use. ``<target>`` is the entry's name (the target with
      ``"/"`` for ``"."``, e.g. ``curriculum/wrapped_task/reward/rewards/effort/R``); a tensor-valued
      target gives one key per entry, ``curriculum/<target>/<i>`` (row-major index, e.g.
      ``curriculum/command/high/0``). The latest frames are the last frame of every row of an
      ``[*envs, time]`` batch; in a flat or padded batch, whose rows are not envs, the valid frames
      with the largest frame count (the last frame of each env, when the envs share one count), so
      these layouts need the Curriculum's ``frames`` entry (a ``ValueError`` says so without it, e.g.
      for a :class:`~torchtasks.transforms.DifficultyLevels` alone). The values are means over those
      frames, i.e. over the envs, which hold the same values when they share one Curriculum. Data
      without the entries give none of these keys.
    - ``ended_by/<name>`` (when the data holds a task's named end conditions ``("next", ended_by_key, name)``,
      as a :class:`~torchtasks.transforms.TaskTransform` writes them for a tree that names its failures,
      e.g. ``out_of_bounds`` and ``unhealthy``): the fraction of the ended episodes whose last frame has
      that condition. Conditions may hold together; an episode ended by the time limit or by the env
      has none (see ``timeout_rate`` and ``env_termination_rate``).
    - ``cost_mean/<name>`` (when the data holds a task's costs ``("next", cost_terms_key, name)``, as a
      :class:`~torchtasks.transforms.TaskTransform` of a :class:`~torchtasks.tasks.ConstrainedTask` writes
      them): the mean over the complete episodes of the episode's summed cost, per constraint; with
      ``cost_limits={name: limit}`` also ``cost_violation_rate/<name>``, the fraction of those episodes
      whose summed cost exceeds the limit.
    - ``group_return_mean/<name>`` (when the data holds a task's reward groups ``("next", groups_key, name)``, as a
      :class:`~torchtasks.transforms.TaskTransform` of a :class:`~torchtasks.tasks.RewardGroupsTask` writes them):
      the mean over the complete episodes of the episode's summed group, per group (the per-objective returns).
    - ``domain/<field>`` (when the data holds a :class:`~torchtasks.transforms.DomainRandomization`'s entries
      ``("next", domain_key, field)``): the mean over the ended episodes of the field's value at the episode's
      last frame (the physics that episode ended with), beside the outcome rates; a vector field gives one key
      per entry, ``domain/<field>/<i>`` (e.g. ``domain/gravity/2``).
    - ``observation_bias_rms/<entry>`` (when the data holds an :class:`~torchtasks.transforms.ObservationNoise`'s
      biases ``("next", "<bias_key>_<entry>")``): the root mean square over the ended episodes and the
      entry's elements of the bias each episode ended with (an estimate of the bias std; a nested entry's parts
      joined with ``:``, as in its field names).
    - ``push_steps_mean/<kind>`` (when the data holds a :class:`~torchtasks.transforms.Pushes`' entries
      ``("next", "<push_key>_velocity")`` or ``("next", "<push_key>_wrench")``): the steps of an episode in which
      the entry is not zero, mean over the complete episodes: for ``velocity`` the pushes (velocity changes) per
      episode, for ``wrench`` the steps under a force.
    - ``curriculum/level`` and ``curriculum/level_fraction/<k>`` (when the data holds a
      :class:`~torchtasks.transforms.DifficultyLevels`' integer entry ``("next", curriculum_key, "level")``):
      at the same latest frames, the mean level over the envs and the fraction of envs at level ``k``,
      for ``k`` from 0 to the highest level reached.

    Args:
        batch: collected frames, TorchRL layout (flags and rewards under ``"next"``).
        reward_key, success_key, failure_key: entries under ``"next"``; ``None`` skips the statistics that
            need one. A key that is given but missing raises ``KeyError``, except the default ``"success"`` and
            ``"failure"``: a :class:`~torchtasks.transforms.TaskTransform` writes the success flag only for a tree
            that can succeed and the failure flag only for one that can fail, so data without the default flag
            report no such rate (and count that outcome as never happening for ``timeout_rate`` and
            ``env_termination_rate``).
        terms_key: the TaskTransform's ``terms_key`` (the reward breakdown under ``"next"``); data without
            it report no per-term returns, as for the other optional entries below (a TaskTransform writes
            a breakdown only for a tree that has terms or a final reward): check the returned keys when you
            pass your own key. ``None`` skips them.
        goal_key, achieved_goal_key: entries ``[*B, k]`` holding the goal (read at the root) and the
            achieved goal (read under ``"next"``). A key that starts with ``"next"`` is read as
            written: a goal carried in the task memory is the one the step was judged with in the
            memory after the step (e.g. ``("next", "task", "wrapped", "state_des")``; the memory at
            the root holds the previous step's goal when a ``goal_key`` feeds the task).
        cost_terms_key: the TaskTransform's ``cost_terms_key`` (per-constraint costs under ``"next"``); data
            without it report no costs; ``None`` skips them.
        ended_by_key: the TaskTransform's ``ended_by_key`` (named end conditions under ``"next"``); data
            without it report none; ``None`` skips them.
        groups_key: the TaskTransform's ``groups_key`` (one entry per reward group under ``"next"``); data
            without it report no group returns; ``None`` skips them.
        cost_limits: ``{cost name: limit}`` for the violation rates (e.g. ``task.cost_limits`` without the
            ``None`` ones); a name that is not a cost of the data is a ``KeyError``.
        curriculum_key: the Curriculum's ``curriculum_key`` (its entries are read under ``"next"``);
            data without it report no scheduled values; ``None`` skips them.
        domain_key: the DomainRandomization's ``entry_key`` (the drawn physics under ``"next"``); data without it
            report no domain values; ``None`` skips them.
        bias_key, push_key: the ObservationNoise's and the Pushes' ``entry_key`` (the prefix of their entries);
            data without them report no biases and no pushes; ``None`` skips them.
        time_dim: the time dim of a ``[*envs, time]`` batch; by default the last one (or, for a 1-D
            batch with the collector's trajectory ids, the flat layout).
        mask_key: the padding mask of a padded batch (bool, at the root, False on padding; TorchRL writes
            ``("collector", "mask")``, or ``"mask"`` beside a ``split_trajectories(trajectory_key=...)``);
            data without it hold no padding; ``None``: every frame is a collected one.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> def flags(*values):  # one env, five frames: [1, 5, 1]
        ...     return torch.tensor(values).reshape(1, 5, 1)
        >>> batch = TensorDict({"next": {
        ...     "done": flags(0, 1, 0, 0, 1).bool(), "terminated": flags(0, 1, 0, 0, 0).bool(),
        ...     "truncated": flags(0, 0, 0, 0, 1).bool(), "success": flags(0, 1, 0, 0, 0).bool(),
        ...     "failure": flags(0, 0, 0, 0, 0).bool(), "step_count": flags(1, 2, 1, 2, 3),
        ...     "reward": flags(1.0, 2.0, 0.5, 0.5, 0.5),
        ...     "task_reward": {"step": flags(1.0, 1.0, 0.5, 0.5, 0.5), "final": flags(0.0, 1.0, 0.0, 0.0, 0.0)},
        ... }}, batch_size=[1, 5])
        >>> stats = episode_statistics(batch)
        >>> stats["episodes"], stats["success_rate"], stats["timeout_rate"], stats["episode_length_mean"]
        (2.0, 0.5, 0.5, 2.5)
        >>> stats["return_mean"], stats["return_mean/final"]
        (2.25, 0.5)
    """
    if not isinstance(batch, TensorDictBase):
        raise TypeError(f"episode_statistics: batch must be a TensorDict, got {type(batch).__name__}")
    if (goal_key is None) != (achieved_goal_key is None):
        raise ValueError("episode_statistics: give both goal_key and achieved_goal_key, or neither")
    keys = {
        name: None if value is None else key_parts(nested_key(value, f"episode_statistics: {name}"))
        for name, value in (
            ("reward_key", reward_key),
            ("success_key", success_key),
            ("failure_key", failure_key),
            ("terms_key", terms_key),
            ("goal_key", goal_key),
            ("achieved_goal_key", achieved_goal_key),
            ("curriculum_key", curriculum_key),
            ("domain_key", domain_key),
            ("bias_key", bias_key),
            ("push_key", push_key),
            ("cost_terms_key", cost_terms_key),
            ("ended_by_key", ended_by_key),
            ("groups_key", groups_key),
            ("mask_key", mask_key),
        )
    }
    limits = _cost_limits(cost_limits)
    with torch.no_grad():
        return _statistics(batch, keys, limits, _time_dim(batch, time_dim))


def _cost_limits(cost_limits: object) -> dict[str, float]:
    if cost_limits is None:
        return {}
    if not isinstance(cost_limits, Mapping):
        raise TypeError(f"episode_statistics: cost_limits must be a mapping {{cost name: limit}}, got {cost_limits!r}")
    limits = {}
    for name, limit in cost_limits.items():
        if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not math.isfinite(limit) or limit < 0:
            raise ValueError(f"episode_statistics: cost_limits[{name!r}] must be a finite number >= 0, got {limit!r}")
        limits[name] = float(limit)
    return limits


def _statistics(
    batch: TensorDictBase, keys: dict[str, tuple[str, ...] | None], limits: dict[str, float], time_dim: int | None
) -> dict[str, float]:
    frames = _Frames(batch, time_dim)
    # every entry that a given key names is read (and checked) up front, whether or not an episode ended
    done = _required(frames, (DONE_KEY,), DONE_KEY, flag=True)
    # the task's outcome flags: a TaskTransform writes the default ones only for the outcomes the tree defines
    # (no success flag for a tree that cannot succeed), so an absent default flag means "never"; another key that
    # is given must be in the data. `verdicts_known`: every outcome is either read or known never to happen.
    flags: dict[str, torch.Tensor] = {}
    verdicts_known = True
    for name, default in (("success", SUCCESS_KEY), ("failure", FAILURE_KEY)):
        key = keys[f"{name}_key"]
        if key is None:
            verdicts_known = False
        elif key != (default,) or frames.get(key) is not None:
            flags[name] = _required(frames, key, f"{name}_key", flag=True)
    terminated = frames.flag((TERMINATED_KEY,), TERMINATED_KEY)
    truncated = frames.flag((TRUNCATED_KEY,), TRUNCATED_KEY)
    step_count = frames.scalar((STEP_COUNT_KEY,), STEP_COUNT_KEY)
    is_init = frames.flag((IS_INIT_KEY,), IS_INIT_KEY, where="root")
    valid = None if keys["mask_key"] is None else _valid_frames(frames, keys["mask_key"])
    returns: dict[str, torch.Tensor] = {}
    if keys["reward_key"] is not None:
        returns["return_mean"] = _required(frames, keys["reward_key"], "reward_key")
    for name, value in _named_entries(frames, keys["terms_key"], "terms_key").items():
        returns["return_mean/" + name] = value
    # per named end condition: its flag at every frame; per constraint: the cost of every frame
    end_flags = _named_entries(frames, keys["ended_by_key"], "ended_by_key", flag=True)
    costs = _named_entries(frames, keys["cost_terms_key"], "cost_terms_key")
    unknown = sorted(set(limits) - set(costs))
    if unknown:
        raise KeyError(
            f"episode_statistics: cost_limits names {unknown}, which are not costs of the data (its costs under "
            f"('next', *{keys['cost_terms_key']!r}): {sorted(costs)})"
        )
    for name, value in costs.items():
        returns["cost_mean/" + name] = value
    for name, value in _named_entries(frames, keys["groups_key"], "groups_key").items():
        returns["group_return_mean/" + name] = value
    # per domain field: its values at every frame, [F, elements]
    domain = {
        "/".join(name): _required_vector(frames, (*keys["domain_key"], *name), "domain_key", where="next")
        for name in _leaf_names(batch, keys["domain_key"])
    }
    # per noisy entry: the episode's bias at every frame, [F, elements]; per kind of push: pushed frames, summed
    biases = {
        name: _required_vector(frames, record_entry(keys["bias_key"], name), "bias_key", where="next")
        for name in _suffixes(batch, keys["bias_key"])
    }
    for record in () if keys["push_key"] is None else PUSH_RECORDS:
        key = record_entry(keys["push_key"], record)
        if batch.get(("next", *key), None) is not None:
            pushed = _required_vector(frames, key, "push_key", where="next") != 0
            returns["push_steps_mean/" + record] = pushed.any(-1)
    goals = None
    if keys["goal_key"] is not None:
        goals = (  # the goal that judged step t, and the goal achieved by it
            _required_vector(frames, keys["goal_key"], "goal_key", where="root"),
            _required_vector(frames, keys["achieved_goal_key"], "achieved_goal_key", where="next"),
        )
        if goals[0].shape != goals[1].shape:
            raise ValueError(
                "episode_statistics: goal_key and achieved_goal_key hold different sizes per frame "
                f"({list(goals[0].shape[1:])} and {list(goals[1].shape[1:])})"
            )
    schedule = {} if keys["curriculum_key"] is None else _schedule(frames, keys["curriculum_key"], valid)
    device = done.device

    # ------------------------------------------------------------- episode id of every frame
    start = torch.zeros_like(done)  # frames known to be the first of their episode
    if time_dim is None:  # flat: one collector trajectory id per episode
        traj_ids = frames.scalar(TRAJ_IDS_KEY, "traj_ids", where="root")
        _, ids = torch.unique(traj_ids, return_inverse=True)
        slots = int(ids.max()) + 1 if ids.numel() else 0
    else:  # rows of consecutive frames: a new episode after every done frame
        rows = done.reshape(frames.rows, frames.steps)
        index = torch.cumsum(rows, dim=1) - rows.long()  # episode number within the row; the done frame ends it
        slots = frames.rows * (frames.steps + 1)
        offsets = torch.arange(frames.rows, device=device).unsqueeze(1) * (frames.steps + 1)
        ids = (index + offsets).reshape(-1)
        start = start.reshape(frames.rows, frames.steps)
        start[:, 1:] = rows[:, :-1]
        start = start.reshape(-1)
    if is_init is not None:
        start = start | is_init
    if valid is not None:  # padding: in no episode (a slot of its own), never an end or a start
        done, start = done & valid, start & valid
        ids = torch.where(valid, ids, slots)
        slots += 1
    if time_dim is None and step_count is not None:
        _check_frames_once(ids if valid is None else ids[valid], step_count if valid is None else step_count[valid])

    ends = torch.nonzero(done).squeeze(-1)  # the last frame of every ended episode
    episode = ids[ends]
    n_ended = ends.numel()
    if n_ended and time_dim is None and torch.bincount(episode).max() > 1:
        raise ValueError(
            "episode_statistics: a collector trajectory id has more than one done frame; a flat batch needs one "
            "trajectory id per episode, as TorchRL collectors write them"
        )
    stats: dict[str, float] = {"episodes": float(n_ended)}
    if n_ended == 0:
        stats["complete_episodes"] = 0.0
        stats.update(_floats(schedule))
        return stats

    frames_per_episode = torch.bincount(ids, minlength=slots)
    if step_count is not None:  # the length of every ended episode, wherever it started
        length = step_count[ends]
        complete = frames_per_episode[episode] == length
    else:
        starts = torch.zeros(slots, dtype=torch.long, device=device).index_add_(0, ids, start.long())
        complete = starts[episode] > 0
        length = frames_per_episode[episode]
    n_complete = int(complete.sum())
    stats["complete_episodes"] = float(n_complete)

    # ------------------------------------------------------------- how the episodes ended
    results: dict[str, torch.Tensor] = {}
    for name, flag in flags.items():
        results[f"{name}_rate"] = _mean(flag[ends])
    for name, flag in end_flags.items():
        results[f"ended_by/{name}"] = _mean(flag[ends])
    if terminated is not None or truncated is not None:
        if terminated is None:
            terminated = done & ~truncated
        if truncated is None:
            truncated = done & ~terminated
        task_end = torch.zeros_like(ends, dtype=torch.bool)
        for flag in flags.values():
            task_end = task_end | flag[ends]
        end_terminated = terminated[ends]
        results["timeout_rate"] = _mean(truncated[ends] & ~end_terminated & ~task_end)
        if verdicts_known:  # the env's own termination: terminated, and the task said neither success nor failure
            results["env_termination_rate"] = _mean(end_terminated & ~task_end)

    # ------------------------------------------------------------- lengths and returns
    if step_count is not None:
        results["episode_length_mean"] = _mean(length)
    elif n_complete:
        results["episode_length_mean"] = _mean(length[complete])
    if n_complete:
        for stat, value in returns.items():
            sums = torch.zeros(slots, dtype=torch.float64, device=device).index_add_(0, ids, value.to(torch.float64))
            results[stat] = sums[episode][complete].mean()
            name = stat[len("cost_mean/") :]
            if stat.startswith("cost_mean/") and name in limits:
                results["cost_violation_rate/" + name] = _mean(sums[episode][complete] > limits[name])
    for name, values in domain.items():  # the physics each ended episode ended with
        means = values[ends].to(torch.float64).mean(0)
        if means.numel() == 1:
            results[f"{DOMAIN_KEY}/{name}"] = means[0]
        else:
            results.update({f"{DOMAIN_KEY}/{name}/{i}": mean for i, mean in enumerate(means)})
    for name, values in biases.items():  # the bias each ended episode ended with
        results[f"observation_bias_rms/{name}"] = values[ends].to(torch.float64).square().mean().sqrt()
    if goals is not None:
        goal, achieved = (value[ends].to(torch.float64) for value in goals)
        results["final_goal_distance_mean"] = torch.linalg.vector_norm(goal - achieved, dim=-1).mean()

    results.update(schedule)
    stats.update(_floats(results))
    return stats


def _floats(results: dict[str, torch.Tensor]) -> dict[str, float]:
    """0-d tensors as plain floats, with one device-to-host copy."""
    values = torch.stack([value.to(torch.float64) for value in results.values()]).tolist() if results else []
    return dict(zip(results, values, strict=True))


def _mean(values: torch.Tensor) -> torch.Tensor:
    return values.to(torch.float64).mean()


def _valid_frames(frames: _Frames, key: tuple[str, ...]) -> torch.Tensor | None:
    """The padding mask at the root as ``[F]`` bool (True: a collected frame), None without one; padding must come
    after the valid frames of each row, as TorchRL pads trajectories."""
    valid = frames.scalar(key, "mask_key", where="root")
    if valid is None:
        return None
    if valid.dtype != torch.bool:
        raise TypeError(
            f"episode_statistics: mask_key={key if len(key) > 1 else key[0]!r} must hold a bool mask (True on the "
            f"collected frames, False on padding), got dtype {valid.dtype}"
        )
    if frames.time_dim is not None and frames.count:
        rows = valid.reshape(frames.rows, frames.steps)
        if (rows[:, 1:] & ~rows[:, :-1]).any():
            raise ValueError(
                f"episode_statistics: the mask mask_key={key if len(key) > 1 else key[0]!r} has a valid frame after "
                "padding in a row along time_dim; a padded batch (split_trajs=True) holds each row's frames first "
                "and its padding after them"
            )
    return valid


def _check_frames_once(ids: torch.Tensor, step_count: torch.Tensor) -> None:
    """Refuse a flat batch that holds a frame twice (one trajectory id, one step count), e.g. a replay-buffer sample
    drawn with replacement: its episodes' frames would be counted twice."""
    pairs = torch.stack([ids, step_count.to(ids.dtype)])
    if torch.unique(pairs, dim=1).shape[1] < ids.numel():
        raise ValueError(
            "episode_statistics: a flat batch holds some frame twice (the same collector trajectory id and "
            "('next', 'step_count')), e.g. a replay-buffer sample drawn with replacement; statistics count each "
            "frame once: sample without replacement (SamplerWithoutReplacement) or pass distinct frames"
        )


def _schedule(frames: _Frames, key: tuple[str, ...], valid: torch.Tensor | None) -> dict[str, torch.Tensor]:
    """The Curriculum's entries ``("next", *key, ...)`` at the latest frame as ``curriculum/<name>``; {} if none."""
    entries = frames.batch.get(("next", *key), None)
    if entries is None or frames.count == 0:
        return {}
    if not isinstance(entries, TensorDictBase):
        raise TypeError(
            f"episode_statistics: ('next', *{key!r}) must hold a Curriculum's entries (a TensorDict); pass the "
            "Curriculum's curriculum_key, or curriculum_key=None"
        )
    names = [(name,) if isinstance(name, str) else tuple(name) for name in entries.keys(True, True)]
    if frames.time_dim is not None and valid is None:  # rows of env frames: the last frame of every row
        latest = torch.arange(frames.rows) * frames.steps + frames.steps - 1
    else:  # flat, or rows of padded trajectories: the valid frames with the largest frame count
        count = frames.get((*key, FRAMES))
        if count is None:  # e.g. DifficultyLevels without a Curriculum: nothing tells which frames are the latest
            layout = "a flat batch" if frames.time_dim is None else "a padded batch (rows are trajectories, not envs)"
            raise ValueError(
                f"episode_statistics: the entries ('next', *{key!r}) of {layout} are read at its latest frames, "
                f"found by a Curriculum's frame count ('next', *{key!r}, {FRAMES!r}), which this batch "
                "does not hold; pass the batch time-major and unpadded ([*E, T], as a collector returns it with "
                "split_trajs=False), add a Curriculum to the env, or pass curriculum_key=None to leave these "
                "statistics out"
            )
        count = count.reshape(frames.count, -1)[:, 0]
        if valid is not None:
            if not valid.any():  # nothing but padding: no latest frame
                return {}
            count = torch.where(valid, count, count.min() - 1)
        latest = torch.nonzero(count == count.max()).squeeze(-1)
    schedule: dict[str, torch.Tensor] = {}
    for name in names:
        value = frames.get((*key, *name))
        value = value[latest.to(value.device)]
        stat = CURRICULUM_PREFIX + "/".join(name)
        if name == (LEVEL,) and not value.is_floating_point():  # DifficultyLevels: one level per env
            schedule.update(_level_stats(value.reshape(-1), stat))
            continue
        value = value.to(torch.float64).mean(0).reshape(-1)  # mean over the envs, then one value per entry
        if value.numel() == 1:
            schedule[stat] = value[0]
        else:
            schedule.update((f"{stat}/{i}", entry) for i, entry in enumerate(value))
    return schedule


def _level_stats(levels: torch.Tensor, stat: str) -> dict[str, torch.Tensor]:
    """Per-env levels (int ``[N]``) as their mean (``stat``) and the fraction of envs at each level up to the highest
    (``stat + "_fraction/<k>"``)."""
    counts = torch.bincount(levels.cpu())
    fractions = counts.to(torch.float64) / levels.numel()
    result = {stat: levels.to(torch.float64).mean()}
    result.update((f"{stat}_fraction/{k}", fraction) for k, fraction in enumerate(fractions))
    return result


def _leaf_names(batch: TensorDictBase, key: tuple[str, ...] | None) -> list[tuple[str, ...]]:
    """The leaves of the node ``("next", *key)`` of ``batch`` as key tuples (none: no such node)."""
    node = None if key is None else batch.get(("next", *key), None)
    if not isinstance(node, TensorDictBase):
        return []
    return [key_parts(name) for name in node.keys(True, True)]


def _suffixes(batch: TensorDictBase, prefix: tuple[str, ...] | None) -> list[str]:
    """The ``<suffix>`` of each leaf ``("next", *prefix[:-1], "<prefix[-1]>_<suffix>")`` of ``batch``, in order."""
    if prefix is None:
        return []
    node = batch.get(("next", *prefix[:-1]), None)
    if not isinstance(node, TensorDictBase):
        return []
    start = prefix[-1] + "_"
    return [
        key[len(start) :]
        for key, value in node.items()
        if isinstance(key, str)
        and key.startswith(start)
        and len(key) > len(start)
        and not isinstance(value, TensorDictBase)
    ]


def _required_vector(frames: _Frames, key: tuple[str, ...], name: str, *, where: str) -> torch.Tensor:
    """The entry ``key`` at the root or under ``"next"`` (``where``) as ``[F, k]``; a ``("next", ...)`` key as is."""
    if key[0] == "next":
        where = "root"
    value = frames.get(key, where=where)
    if value is None:
        place = "at the root" if where == "root" else "under 'next'"
        raise KeyError(
            f"episode_statistics: {name}={key if len(key) > 1 else key[0]!r} is not in the data (looked {place}); "
            f"available keys are {keys_text(frames.batch.keys(True, True))}"
        )
    return value.reshape(frames.count, -1)
