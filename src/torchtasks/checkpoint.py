"""Checkpoints that include the base env: :class:`BaseEnvState`, a no-op transform carrying ``base_env.state_dict()``.

TorchRL's ``TransformedEnv.state_dict()``, and so ``Collector.state_dict()``, saves the transforms of a
``TransformedEnv`` but not its base env, whose state (the reset generators of
:class:`~torchtasks.envs.PendulumEnv`, :class:`~torchtasks.envs.PointMassEnv` and
:class:`~torchtasks.envs.BatchedMujocoEnv`) a resumed run needs to draw what the saved run would
have drawn next. A :class:`BaseEnvState` in the transform chain makes the base env's state part of the
transforms' state, so TorchRL's own recipe covers it:
``collector.state_dict()`` -> ``torch.save`` -> a new process builds the same collector ->
``collector.load_state_dict(torch.load(...))``, also in ``ParallelEnv`` workers (whose state is one
``TransformedEnv.state_dict()`` per worker) and ``MultiSyncCollector`` workers. Seed the run with
``env.set_seed``/``collector.set_seed`` (:mod:`torchtasks.seeding`) so that every generator is one the
checkpoint holds: torch's global generator (used by a ``GoalCommand`` never seeded) is not saved.

What is not saved: the states of the running episodes. TorchRL starts fresh trajectories after
loading a collector; call ``collector.reset()`` after loading, and the resumed run equals an
uninterrupted one on which ``collector.reset()`` was called at the same frame.

A TorchRL 0.14.1 bug to know of: ``ParallelEnv.load_state_dict`` with shared buffers (the default
``use_buffers``) leaves its workers' done flags set, so the next reset or step may return before
the workers are done and hand back stale data (fixed upstream in pytorch/rl#4341). Until then build
a ``ParallelEnv`` that loads a checkpoint with ``use_buffers=False``; a ``MultiSyncCollector``
(whose workers load into their own envs) is not affected.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tensordict import TensorDictBase
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.transforms import Transform

from torchtasks._torchrl import container_env, flat_transforms

__all__ = ["BaseEnvState"]


class BaseEnvState(Transform):
    """Carry the base env's ``state_dict()`` in the transforms' state, so collector checkpoints restore the base env.

    A transform that does nothing to the data (its step, reset and inverse return their input
    untouched: it costs a few Python calls per step). Its ``state_dict()`` holds, under
    ``"_extra_state"``, the ``state_dict()`` of the ``base_env`` of the ``TransformedEnv`` it sits in;
    ``load_state_dict`` loads it into that base env (``strict``, as ``nn.Module.load_state_dict``).
    Put it last in the ``Compose`` (anywhere works; last keeps the indices of the other transforms'
    state entries as they were). With a ``TransformedEnv`` nested in another (``auto_unwrap=False``),
    put it in the outermost env: TorchRL's ``Collector.state_dict()`` saves that env's transforms only.
    Its base env is then the inner ``TransformedEnv``, whose ``state_dict()`` is the inner transforms';
    unless the inner env holds a ``BaseEnvState`` of its own, the state of the env below it is saved
    too (under ``"_inner_base_env"``), down to the innermost base env.

    Loading or saving it outside a ``TransformedEnv`` (e.g. a ``Compose`` not yet in an env) raises a
    ``ValueError``: the state belongs to an env, so load it once the env is built.

    Example:
        >>> import io, torch
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl.collectors import Collector
        >>> from torchrl.envs import Compose, StepCounter, TransformedEnv
        >>> from torchtasks.checkpoint import BaseEnvState
        >>> from torchtasks.envs import PendulumEnv
        >>> def make_collector():
        ...     env = TransformedEnv(PendulumEnv(batch_size=[4]), Compose(StepCounter(10), BaseEnvState()))
        ...     policy = TensorDictModule(torch.nn.Linear(2, 1), ["observation"], ["action"])
        ...     return Collector(env, policy, frames_per_batch=20, total_frames=-1,
        ...                      auto_register_policy_transforms=False)
        >>> running = make_collector()
        >>> _ = running.set_seed(0)
        >>> batches = iter(running)
        >>> _ = next(batches)
        >>> buffer = io.BytesIO()
        >>> torch.save(running.state_dict(), buffer)
        >>> _ = buffer.seek(0)
        >>> resumed = make_collector()  # e.g. in a new process
        >>> resumed.load_state_dict(torch.load(buffer))
        >>> running.reset(), resumed.reset()  # loading starts fresh trajectories: start them in both
        (None, None)
        >>> torch.equal(next(batches)["observation"], next(iter(resumed))["observation"])
        True
        >>> running.shutdown(); resumed.shutdown()
    """

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[])

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
        """The base env's ``state_dict()`` (a dict of its entries), and the envs' below it (see the class)."""
        return _env_state(self._base_env("save"))

    def set_extra_state(self, state: Any) -> None:
        """Load ``state`` (as :meth:`get_extra_state` returns it) into the base env (and the envs below it)."""
        _load_env_state(self._base_env("load"), state)


_INNER = "_inner_base_env"  # the state of the env below an inner TransformedEnv without a BaseEnvState


def _env_state(env: EnvBase) -> dict[str, Any]:
    state = dict(env.state_dict())
    if isinstance(env, TransformedEnv) and not any(isinstance(t, BaseEnvState) for t in flat_transforms(env.transform)):
        state[_INNER] = _env_state(env.base_env)  # TransformedEnv.state_dict() holds its transforms' only
    return state


def _load_env_state(env: EnvBase, state: Any) -> None:
    if not isinstance(state, Mapping):
        raise TypeError(
            "BaseEnvState.load_state_dict: the extra state must be the base env's state_dict (a mapping), "
            f"got {type(state).__name__}"
        )
    state = dict(state)
    inner = state.pop(_INNER, None)
    env.load_state_dict(state)
    if inner is not None:
        if not isinstance(env, TransformedEnv):
            raise ValueError(
                f"BaseEnvState.load_state_dict: the checkpoint holds the state of an env below the base env, but the "
                f"base env is a {type(env).__name__}, not a TransformedEnv: load it into an env built as the saved one"
            )
        _load_env_state(env.base_env, inner)

    # ------------------------------------------------------------------ no-op TorchRL hooks
    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        return next_tensordict

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
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
