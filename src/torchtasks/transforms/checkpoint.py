"""Checkpoints that a resume continues: :class:`BaseEnvState`, :func:`collector_state`, :func:`load_collector_state`.

Two pieces of a run are in no TorchRL ``state_dict``. TorchRL's ``TransformedEnv.state_dict()``, and
so ``Collector.state_dict()``, saves the transforms of a ``TransformedEnv`` but not its base env,
whose state (the reset generators of :class:`~torchtasks.envs.PendulumEnv`,
:class:`~torchtasks.envs.PointMassEnv` and :class:`~torchtasks.envs.BatchedMujocoEnv`, and the
batched env's physics) a resumed run needs: a :class:`BaseEnvState` in the transform chain makes the
base env's state part of the transforms' state, also in ``ParallelEnv`` workers (whose state is one
``TransformedEnv.state_dict()`` per worker) and ``MultiSyncCollector`` workers. And a collector
carries the data of the running episodes from one step to the next outside any ``state_dict`` (the
last observation, step counts, running reward sums, task memory, goals and their timers, trajectory
ids): :func:`collector_state` saves them with ``collector.state_dict()``, and
:func:`load_collector_state` puts them back, so that the batch after a resume equals the
uninterrupted run's, entry for entry. Seed the run with ``env.set_seed``/``collector.set_seed``
(:mod:`torchtasks.transforms.seeding`) so that every generator is one the checkpoint holds: torch's global
generator (used by a ``GoalCommand`` never seeded) is not saved.

What continues: the envs whose ``state_dict`` holds everything their next step reads besides its
input (their extra state has a ``"running_episodes"`` entry): torchtasks' envs. TorchRL's ``GymEnv``
and most other envs keep their simulator state elsewhere; :func:`collector_state` refuses them, and
the recipe for them is TorchRL's: ``collector.load_state_dict`` then ``collector.reset()``, which
starts fresh episodes (the run then equals an uninterrupted one on which ``collector.reset()`` was
called at the same frame).

A TorchRL 0.14.1 bug to know of: ``ParallelEnv.load_state_dict`` with shared buffers (the default
``use_buffers``) leaves its workers' done flags set, so the next reset or step may return before
the workers are done and hand back stale data (fixed upstream in pytorch/rl#4341). Until then build
a ``ParallelEnv`` that loads a checkpoint with ``use_buffers=False`` (:func:`load_collector_state`
refuses one with shared buffers); a ``MultiSyncCollector`` (whose workers load into their own envs)
is not affected.
"""

from __future__ import annotations

import copy
import re
import warnings
from collections.abc import Mapping
from typing import Any

import torch
import torchrl
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.envs import EnvBase, ParallelEnv, TransformedEnv
from torchrl.envs.batched_envs import BatchedEnvBase
from torchrl.envs.transforms import Transform

from torchtasks._checked_load import join_load, refuse_load
from torchtasks._torchrl import container_env, flat_transforms

__all__ = ["BaseEnvState", "collector_state", "load_collector_state"]

#: the entry of an env's extra state that holds its running episodes (what its next step reads besides its input)
RUNNING_EPISODES = "running_episodes"
_INNER = "_inner_base_env"  # the state of the env below an inner TransformedEnv without a BaseEnvState
_BASE_ENV = "_base_env_class"  # marks a BaseEnvState's state: the class name of the env it saved
_CONTINUES = "_continues"  # written by load_collector_state: the collector's carried data are restored too
_LISTED = 4  # the carried entries of another shape an error lists (a batch size changes them all)
_WORKER = re.compile(r"worker\d+")


class BaseEnvState(Transform):
    """Carry the base env's ``state_dict()`` in the transforms' state, so collector checkpoints restore the base env.

    A transform that does nothing to the data (its step, reset and inverse return their input untouched: a few
    Python calls per step). Its ``state_dict()`` holds, under ``"_extra_state"``, the ``state_dict()`` of the
    ``base_env`` of the ``TransformedEnv`` it sits in (and the base env's class name); ``load_state_dict`` loads it
    into that base env (``strict``, as ``nn.Module.load_state_dict``). Put it last in the ``Compose`` (anywhere works;
    last keeps the other transforms' state entries where they were); on a preset that returns a finished
    ``TransformedEnv``, ``env.append_transform(BaseEnvState())``. With a ``TransformedEnv`` nested in another, put it in
    the outermost env: the states of the envs below are saved too (under ``"_inner_base_env"``), down to the innermost
    base env. After a load, the env expects to be reset or to be stepped from data restored with the checkpoint
    (:func:`load_collector_state` restores a collector's): a first step from anything else warns once
    (``UserWarning``). Loading or saving it outside a ``TransformedEnv`` raises a ``ValueError``. The docs page
    "TorchRL integration" (checkpoints and resume) has the recipe.

    Example:
        >>> import io, torch
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl.collectors import Collector
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.transforms import BaseEnvState
        >>> from torchtasks.envs import PendulumEnv
        >>> def make_collector():
        ...     env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(StepCounter(10), BaseEnvState()))
        ...     policy = TensorDictModule(torch.nn.Linear(2, 1), ["observation"], ["action"])
        ...     return Collector(env, policy, frames_per_batch=20, total_frames=-1)
        >>> running = make_collector()
        >>> _ = running.set_seed(0)
        >>> batches = iter(running)
        >>> _ = next(batches)
        >>> buffer = io.BytesIO()
        >>> torch.save(running.state_dict(), buffer)
        >>> _ = buffer.seek(0)
        >>> resumed = make_collector()  # e.g. in a new process
        >>> resumed.load_state_dict(torch.load(buffer))
        >>> running.reset(), resumed.reset()  # TorchRL's recipe starts fresh episodes: start them in both
        (None, None)
        >>> torch.equal(next(batches)["observation"], next(iter(resumed))["observation"])
        True
        >>> running.shutdown(); resumed.shutdown()
    """

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[])
        #: a checkpoint was loaded and no full reset nor load_collector_state followed it yet
        self._stale_after_load = False

    def _base_env(self, action: str) -> EnvBase:
        env = container_env(self)
        if not isinstance(env, TransformedEnv):
            raise ValueError(
                f"BaseEnvState cannot {action} the base env's state: it is not in a TransformedEnv (its env is "
                f"{type(env).__name__}); build the env, e.g. TransformedEnv(base_env, Compose(..., BaseEnvState())), "
                "then call load_state_dict/state_dict on the env or the collector"
            )
        return env.base_env

    # ------------------------------------------------------------------ checkpoints
    def get_extra_state(self) -> dict[str, Any]:
        """The base env's ``state_dict()`` (a dict of its entries), the envs' below it (see the class), its class."""
        base = self._base_env("save")
        state = _env_state(base)
        state[_BASE_ENV] = type(base).__name__
        return state

    def set_extra_state(self, state: Any) -> None:
        """Load ``state`` (as :meth:`get_extra_state` returns it) into the base env (and the envs below it)."""
        base = self._base_env("load")
        if not isinstance(state, Mapping):
            raise TypeError(
                "BaseEnvState.load_state_dict: the extra state must be the base env's state_dict (a mapping), "
                f"got {type(state).__name__}"
            )
        state = dict(state)
        saved_class = state.pop(_BASE_ENV, None)  # absent from checkpoints written before it was saved
        if saved_class is not None and saved_class != type(base).__name__:
            raise ValueError(
                f"BaseEnvState.load_state_dict: the checkpoint holds the state of a {saved_class}, this env's base env "
                f"is a {type(base).__name__}: load it into an env built as the saved one"
            )
        continues = bool(state.pop(_CONTINUES, False))
        _load_env_state(base, state)
        self._stale_after_load = not continues

    def _load_from_state_dict(self, state_dict: Any, prefix: str, *args: Any, **kwargs: Any) -> None:
        # one of the modules of a load: a refusal of the base env puts back the transforms loaded before this one,
        # and a refusal after it puts the base env back (_checked_load)
        try:
            before = None
            if prefix + "_extra_state" in state_dict and isinstance(container_env(self), TransformedEnv):
                before = copy.deepcopy(self.get_extra_state()), self._stale_after_load
            super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        except Exception:
            refuse_load()
            raise
        if before is not None:
            join_load(self, lambda: self._put_back(*before))

    def _put_back(self, state: dict[str, Any], stale: bool) -> None:
        self.set_extra_state(state)
        self._stale_after_load = stale

    # ------------------------------------------------------------------ TorchRL hooks: the data pass unchanged
    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return next_tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self._stale_after_load:
            self._stale_after_load = False
            warnings.warn(
                "BaseEnvState: this env is stepped after load_state_dict without a reset: a collector keeps the data "
                "of the running episodes (last observation, step counts, running sums, task memory, goals, "
                "trajectory ids) outside state_dict, so this step continues the episodes it held before the load, "
                "not the saved ones. Load with torchtasks.transforms.load_collector_state(collector, state) to "
                "continue the saved episodes, or call collector.reset() after collector.load_state_dict(...) to "
                "start fresh ones.",
                UserWarning,
                stacklevel=2,
            )
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        if self._stale_after_load and _resets_every_env(tensordict):
            self._stale_after_load = False
        return tensordict_reset

    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase | None:
        return tensordict

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Return ``tensordict`` unchanged (stored data has no base env to save)."""
        return tensordict

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


def _resets_every_env(tensordict: TensorDictBase | None) -> bool:
    """Whether a reset with this input resets every env (no ``"_reset"`` entry, or all of them True)."""
    if tensordict is None:
        return True
    masks = [
        tensordict.get(key)
        for key in tensordict.keys(True, True)
        if (key if isinstance(key, str) else key[-1]) == "_reset"
    ]
    return all(bool(mask.all()) for mask in masks)


def _env_state(env: EnvBase) -> dict[str, Any]:
    state = dict(env.state_dict())
    if isinstance(env, TransformedEnv) and not any(isinstance(t, BaseEnvState) for t in flat_transforms(env.transform)):
        state[_INNER] = _env_state(env.base_env)  # TransformedEnv.state_dict() holds its transforms' only
    return state


def _load_env_state(env: EnvBase, state: dict[str, Any]) -> None:
    inner = state.pop(_INNER, None)
    env.load_state_dict(state)
    if inner is not None:
        if not isinstance(env, TransformedEnv):
            raise ValueError(
                f"BaseEnvState.load_state_dict: the checkpoint holds the state of an env below the base env, but the "
                f"base env is a {type(env).__name__}, not a TransformedEnv: load it into an env built as the saved one"
            )
        if not isinstance(inner, Mapping):
            raise TypeError(
                f"BaseEnvState.load_state_dict: {_INNER!r} must be the state_dict of the env below (a mapping), "
                f"got {type(inner).__name__}"
            )
        _load_env_state(env.base_env, dict(inner))


# ---------------------------------------------------------------------- collectors
def collector_state(collector: Collector | MultiSyncCollector) -> dict[str, Any]:
    """A checkpoint of ``collector`` that :func:`load_collector_state` continues: what to ``torch.save``.

    A dict of copies (collecting more batches does not change it; ``torch.load`` reads it with
    ``weights_only=True``): ``"state_dict"``, ``collector.state_dict()`` (the policy, the counters,
    the env's transforms with their :class:`BaseEnvState`), and ``"carried"``, one nested dict of
    tensors per worker with the data the collector carries from one step to the next (observation,
    ``step_count``, running sums, task memory, goals and timers, curriculum entries,
    ``("collector", "traj_ids")``).

    For a ``Collector`` (its env here, or in the workers of a ``ParallelEnv``) or a
    ``MultiSyncCollector``; other collectors (``MultiAsyncCollector``, whose workers run ahead of the
    batches handed out) are a ``TypeError``. A ``ValueError`` for ``trajs_per_batch`` (partial
    trajectories are not saved) and for envs whose running episodes the state does not hold, named:
    an env without a :class:`BaseEnvState` over it, or a base env whose ``state_dict`` has no
    ``"running_episodes"`` entry (TorchRL's ``GymEnv``; torchtasks' envs have one).

    Args:
        collector: the collector, between two batches.

    Example:
        >>> import io, torch
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl.collectors import Collector
        >>> from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv
        >>> from torchtasks.transforms import BaseEnvState, collector_state, load_collector_state
        >>> from torchtasks.envs import PendulumEnv, swing_up_task
        >>> from torchtasks.transforms import TaskTransform
        >>> def make_collector():
        ...     env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(
        ...         StepCounter(30), TaskTransform(swing_up_task()), RewardSum(), BaseEnvState()))
        ...     policy = TensorDictModule(torch.nn.Linear(2, 1), ["observation"], ["action"])
        ...     return Collector(env, policy, frames_per_batch=40, total_frames=-1)
        >>> running = make_collector()
        >>> batches = iter(running)
        >>> _ = next(batches)
        >>> buffer = io.BytesIO()
        >>> torch.save(collector_state(running), buffer)
        >>> _ = buffer.seek(0)
        >>> resumed = make_collector()  # e.g. in a new process
        >>> load_collector_state(resumed, torch.load(buffer))
        >>> a, b = next(batches), next(iter(resumed))  # no reset: the episodes go on
        >>> all(torch.equal(a[key], b[key]) for key in a.keys(True, True))
        True
        >>> running.shutdown(); resumed.shutdown()
    """
    multi = _check_collector(collector, "collector_state")
    state = copy.deepcopy(collector.state_dict())
    _refuse_unsaved_episodes(collector, state, multi, "collector_state")
    carried = [carrier.to_dict() for carrier in _carriers(collector, multi, copies=True)]
    return {"state_dict": state, "carried": carried}


def load_collector_state(collector: Collector | MultiSyncCollector, state: Mapping[str, Any]) -> None:
    """Load a :func:`collector_state` checkpoint so that ``collector`` continues the saved run's episodes.

    ``collector`` must be built as the saved one (e.g. afresh in a new process). Before anything is
    written, the carried data of every worker must have the keys, shapes and dtypes of the
    collector's own (keys only in the checkpoint may be the policy's outputs) and the state must hold
    the running episodes of every env, else a ``ValueError`` naming both sides; a ``ParallelEnv``
    with shared buffers is refused (TorchRL 0.14.1's bug, see the module docs). Then
    ``collector.load_state_dict`` runs (where the base envs check their state: batch size, a MuJoCo
    env's model), the carried data are put back and the trajectory counter is set to the saved one.
    Do not call ``collector.reset()`` afterwards: it would end the restored episodes.

    With a deterministic collection the next batches equal the uninterrupted run's, entry for entry;
    with a ``MultiSyncCollector``, except the ids of new trajectories, which the workers draw from one
    shared counter in the order they ask (different in every run).

    Args:
        collector: the collector to load into (not yet iterated, or between two batches).
        state: what :func:`collector_state` returned (e.g. after ``torch.save``/``torch.load``).

    Example:
        >>> import io, torch
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl.collectors import Collector
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.transforms import BaseEnvState, collector_state, load_collector_state
        >>> from torchtasks.envs import PointMassEnv
        >>> def make_collector(batch):
        ...     env = TransformedEnv(PointMassEnv(batch_size=[batch]), Compose(StepCounter(30), BaseEnvState()))
        ...     policy = TensorDictModule(torch.nn.Linear(4, 2), ["observation"], ["action"])
        ...     return Collector(env, policy, frames_per_batch=4 * batch, total_frames=-1)
        >>> running = make_collector(3)
        >>> _ = next(iter(running))
        >>> saved = collector_state(running)
        >>> other = make_collector(2)
        >>> try:
        ...     load_collector_state(other, saved)
        ... except ValueError as error:
        ...     print(str(error)[:73])
        load_collector_state: the checkpoint's carried data of the collector do n
        >>> running.shutdown(); other.shutdown()
    """
    multi = _check_collector(collector, "load_collector_state")
    if not isinstance(state, Mapping) or not {"state_dict", "carried"} <= set(state):
        got = sorted(map(str, state)) if isinstance(state, Mapping) else type(state).__name__
        raise ValueError(
            "load_collector_state: state must be what collector_state() returned, a dict with 'state_dict' and "
            f"'carried', got {got}"
        )
    state_dict, carried = state["state_dict"], state["carried"]
    workers = collector.num_workers if multi else 1
    if not isinstance(carried, (list, tuple)) or len(carried) != workers:
        got = f"{len(carried)} entries" if isinstance(carried, (list, tuple)) else type(carried).__name__
        raise ValueError(
            f"load_collector_state: the checkpoint's 'carried' must hold one entry per worker of this collector "
            f"({workers}), got {got}"
        )
    _refuse_unsaved_episodes(collector, state_dict, multi, "load_collector_state")
    if not multi:
        _refuse_shared_buffer_parallel_envs(collector.env)
    current = _carriers(collector, multi, copies=True)
    outputs = collector.get_distant_attr("_policy_output_keys") if multi else [collector._policy_output_keys]
    restored = [
        _restored_carrier(saved, own, keys, f"worker {i}" if multi else "the collector")
        for i, (saved, own, keys) in enumerate(zip(carried, current, outputs, strict=True))
    ]
    before = copy.deepcopy(collector.state_dict())  # a module refusing its state leaves the ones before it loaded
    try:
        _put(collector, state_dict, restored, multi)
    except Exception:
        _put(collector, before, current, multi)  # the collector as it was: a refused load changes nothing
        raise


def _put(collector: Collector | MultiSyncCollector, state_dict: Any, carriers: list, multi: bool) -> None:
    """Load ``state_dict`` into ``collector`` and give it ``carriers`` and the saved trajectory counter."""
    collector.load_state_dict(_marked_continuing(state_dict))
    if multi:
        collector.map_fn("__setattr__", [("_carrier", carrier) for carrier in carriers])
    else:
        collector._carrier = carriers[0]
    counter = state_dict.get("traj_pool")
    if counter is not None:  # load_state_dict drew fresh ids for the carried data: the saved counter goes on
        collector._traj_pool.load_state_dict(counter)


def _check_collector(collector: object, caller: str) -> bool:
    """Whether ``collector`` is a MultiSyncCollector (else a Collector); raise for what cannot be continued."""
    if isinstance(collector, MultiAsyncCollector):
        raise TypeError(
            f"{caller}: a MultiAsyncCollector cannot be checkpointed so that a resume continues: its workers collect "
            "the next batches while the last one is consumed, so their state is ahead of the data handed out. Use a "
            "Collector or a MultiSyncCollector, or TorchRL's state_dict/load_state_dict with collector.reset() "
            "(fresh episodes)."
        )
    if not isinstance(collector, (Collector, MultiSyncCollector)):
        raise TypeError(
            f"{caller}: collector must be a Collector or a MultiSyncCollector, got {type(collector).__name__}"
        )
    multi = isinstance(collector, MultiSyncCollector)
    for name in ("trajs_per_batch", "_worker_trajs_per_batch"):
        if getattr(collector, name, None) is not None:
            raise ValueError(
                f"{caller}: the collector assembles trajectories (trajs_per_batch={getattr(collector, name)}); its "
                "partial trajectories are not saved, so a resume cannot continue them. Collect fixed-size batches "
                "(frames_per_batch) to checkpoint a run that continues."
            )
    if not multi and not hasattr(collector, "_carrier"):
        raise RuntimeError(
            f"{caller}: this Collector has no carried data ('_carrier'): it was shut down, or TorchRL "
            f"{torchrl.__version__} keeps them elsewhere (torchtasks.transforms.checkpoint follows TorchRL 0.14's "
            "collectors)"
        )
    return multi


def _carriers(collector: Collector | MultiSyncCollector, multi: bool, *, copies: bool = False) -> list[TensorDictBase]:
    """The data each worker's collector carries to its next step (fetched from the workers if ``multi``).

    The workers send tensors in shared memory, which their next reset may write into: they are always cloned.
    """
    if multi:
        return [carrier.clone() for carrier in collector.get_distant_attr("_carrier")]
    return [collector._carrier.clone() if copies else collector._carrier]


def _leaves(data: Mapping[str, Any], prefix: tuple[str, ...] = ()) -> dict[tuple[str, ...], Any]:
    """The leaves of nested dicts, keyed by their paths."""
    leaves: dict[tuple[str, ...], Any] = {}
    for key, value in data.items():
        if isinstance(value, Mapping):
            leaves.update(_leaves(value, (*prefix, key)))
        else:
            leaves[(*prefix, key)] = value
    return leaves


def _described(value: Any) -> str:
    if isinstance(value, torch.Tensor):
        return f"{value.dtype} {list(value.shape)}"
    return type(value).__name__


def _restored_carrier(saved: Any, own: TensorDictBase, policy_keys: Any, where: str) -> TensorDictBase:
    """The saved carried data as a TensorDict like ``own``; a ``ValueError`` naming both sides if they differ."""
    if not isinstance(saved, Mapping):
        raise ValueError(
            f"load_collector_state: the checkpoint's carried data of {where} must be a dict of tensors, got "
            f"{type(saved).__name__}"
        )
    saved_leaves = _leaves(saved)
    own_leaves = {(key,) if isinstance(key, str) else tuple(key): own.get(key) for key in own.keys(True, True)}
    outputs = {(key,) if isinstance(key, str) else tuple(key) for key in policy_keys}
    batch = list(own.batch_size)
    problems = [
        f"{key}: missing in the checkpoint (this collector: {_described(own_leaves[key])})"
        for key in own_leaves
        if key not in saved_leaves
    ]
    shapes = []  # entries of both, of other dtypes or shapes (a batch size changes them all: a few are listed)
    for key, value in saved_leaves.items():
        mine = own_leaves.get(key)
        if mine is None and key not in outputs:
            problems.append(f"{key}: only in the checkpoint ({_described(value)}), not carried by this collector")
        elif mine is None and (not isinstance(value, torch.Tensor) or list(value.shape[: len(batch)]) != batch):
            shapes.append(f"{key}: {_described(value)} in the checkpoint, this collector's batch is {batch}")
        elif mine is not None and _described(value) != _described(mine):
            shapes.append(f"{key}: {_described(value)} in the checkpoint, {_described(mine)} in this collector")
    problems += shapes[:_LISTED] + ([f"{len(shapes) - _LISTED} more of other shapes"] if len(shapes) > _LISTED else [])
    if problems:
        raise ValueError(
            f"load_collector_state: the checkpoint's carried data of {where} do not fit this collector's (was it "
            f"built as the saved one?): {'; '.join(problems)}"
        )
    carrier = TensorDict(batch_size=own.batch_size, device=own.device)
    for key, value in saved_leaves.items():
        mine = own_leaves.get(key)
        device = mine.device if isinstance(mine, torch.Tensor) else own.device
        carrier.set(key, value.to(device) if isinstance(value, torch.Tensor) and device is not None else value)
    return carrier


def _refuse_unsaved_episodes(
    collector: Collector | MultiSyncCollector, state: Mapping[str, Any], multi: bool, caller: str
) -> None:
    if multi:
        unsaved = [
            where
            for i in range(collector.num_workers)
            for where in _unsaved(
                _worker_env_state(state, i, caller), f"worker{i}/env_state_dict", f"the env of worker {i}"
            )
        ]
    else:
        env_state = state.get("env_state_dict", {}) if isinstance(state, Mapping) else None
        unsaved = _unsaved(env_state, "env_state_dict", f"the collector's env ({type(collector.env).__name__})")
    if unsaved:
        raise ValueError(
            f"{caller}: the checkpoint does not hold the running episodes of {'; '.join(unsaved)}. A resume continues "
            "envs whose state_dict holds them (a 'running_episodes' entry: torchtasks' PendulumEnv, PointMassEnv, "
            "BatchedMujocoEnv) under a BaseEnvState, which puts the base env's state_dict into the transforms' "
            "(TorchRL saves a TransformedEnv's transforms only); TorchRL's GymEnv and most other envs keep their "
            "simulator state outside state_dict. For those, save collector.state_dict() and call collector.reset() "
            "after collector.load_state_dict(): the resumed run starts fresh episodes."
        )


def _worker_env_state(state: Mapping[str, Any], i: int, caller: str) -> Any:
    worker = state.get(f"worker{i}") if isinstance(state, Mapping) else None
    if not isinstance(worker, Mapping):
        raise ValueError(
            f"{caller}: the MultiSyncCollector state has no 'worker{i}' entry (got {sorted(map(str, state))})"
        )
    return worker.get("env_state_dict", {})


def _unsaved(state: Any, where: str, name: str) -> list[str]:
    """The envs below an env's saved ``state`` whose running episodes it does not hold (their names and places)."""
    if not isinstance(state, Mapping):
        return [f"{name} (at {where})"]
    extra = state.get("_extra_state")
    if isinstance(extra, Mapping) and RUNNING_EPISODES in extra:
        return []
    if isinstance(state.get(_INNER), Mapping):
        return _unsaved(state[_INNER], f"{where}/{_INNER}", f"the env below {name}")
    workers = [key for key in state if isinstance(key, str) and _WORKER.fullmatch(key)]
    if workers:
        return [found for key in workers for found in _unsaved(state[key], f"{where}/{key}", f"{key} of {name}")]
    for key, value in state.items():
        if isinstance(value, Mapping) and _BASE_ENV in value:  # a BaseEnvState's: the base env's state
            return _unsaved(value, f"{where}/{key}", str(value[_BASE_ENV]))
    return [f"{name} (at {where})"]


def _marked_continuing(state: Any) -> Any:
    """``state`` with every BaseEnvState's entry marked as continued (copies of the mappings on the way only)."""
    if not isinstance(state, Mapping):
        return state
    marked = copy.copy(state)  # keeps an OrderedDict's _metadata (module versions)
    for key, value in state.items():
        marked[key] = _marked_continuing(value)
    if _BASE_ENV in marked:
        marked[_CONTINUES] = True
    return marked


def _refuse_shared_buffer_parallel_envs(env: EnvBase) -> None:
    """Refuse a ParallelEnv with shared buffers below ``env``: TorchRL's load leaves stale done flags (0.14.1)."""
    while True:
        if isinstance(env, ParallelEnv) and env._use_buffers:
            raise ValueError(
                "load_collector_state: a ParallelEnv with shared buffers cannot load a checkpoint: TorchRL 0.14.1's "
                "ParallelEnv.load_state_dict leaves the workers' done flags set, so the next step returns stale data "
                "(fixed upstream in pytorch/rl#4341). Build the ParallelEnv with use_buffers=False."
            )
        if isinstance(env, TransformedEnv):
            env = env.base_env
        elif isinstance(env, BatchedEnvBase) and not isinstance(env, ParallelEnv):
            envs = getattr(env, "_envs", None) or []
            for worker in envs:
                _refuse_shared_buffer_parallel_envs(worker)
            return
        else:
            return
