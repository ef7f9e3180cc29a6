"""A transform that finds entries sharing storage across frames: :class:`StorageProbe`, and :func:`probed` envs.

TorchRL moves a step's ``"next"`` entries to the root of the next frame (``step_mdp``); every other pair of entries of
two frames must be distinct tensors: an entry under ``"next"`` that shares its storage with an entry of the root of
its frame, or with one the previous step wrote, is changed by whatever writes the other in place (a ``ParallelEnv``
worker copies each step's output into shared buffers, root after ``"next"``; a rollout's frames are stacked at its
end). Placed last in an env's ``Compose``, the probe sees every step's root and ``"next"`` after all the other
transforms wrote, counts such pairs and writes the count per frame under ``ALIASES`` (so it reaches the parent from
worker processes too); in-process, :attr:`StorageProbe.found` names them.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import TransformedEnv
from torchrl.envs.transforms import Transform

#: where the probe writes how many entries under "next" share storage with the frame's root or the previous "next"
ALIASES = ("probe", "aliases")


def _storages(tensordict: TensorDictBase) -> dict[int, list]:
    """Storage address -> the keys of the non-empty tensors of ``tensordict`` (nested) stored there."""
    found: dict[int, list] = {}
    for key, value in tensordict.items(include_nested=True, leaves_only=True):
        if isinstance(value, torch.Tensor) and value.numel():
            found.setdefault(value.untyped_storage().data_ptr(), []).append(key)
    return found


class StorageProbe(Transform):
    """Count, at every step, the entries under ``"next"`` that share storage with the root or the previous step."""

    def __init__(self) -> None:
        super().__init__()
        #: ``(step, key under "next", where its storage is also found)`` of every shared storage seen in this process
        self.found: list[tuple[int, object, str]] = []
        self._previous: dict[int, list] = {}
        self._kept: TensorDictBase | None = None  # the previous "next" entries, alive: no address reused meanwhile
        self._steps = 0

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[ALIASES] = Unbounded(shape=observation_spec.shape, dtype=torch.int64)
        return observation_spec

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        tensordict_reset.set(ALIASES, torch.zeros(tensordict_reset.batch_size, dtype=torch.int64))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        root = _storages(tensordict.exclude("next", ALIASES))
        written = next_tensordict.exclude(ALIASES)
        count = 0
        for address, keys in _storages(written).items():
            for where, known in (("the root", root), ("the previous step", self._previous)):
                if address in known:
                    count += len(keys)
                    self.found.extend((self._steps, key, f"{where} {known[address]}") for key in keys)
        self._previous, self._kept = _storages(written), written
        self._steps += 1
        next_tensordict.set(ALIASES, torch.full(next_tensordict.batch_size, count, dtype=torch.int64))
        return next_tensordict


def probed(make_env: Callable[..., TransformedEnv], *args: object, **kwargs: object) -> TransformedEnv:
    """``make_env(*args, **kwargs)`` with a :class:`StorageProbe` appended (module-level: worker processes build it)."""
    env = make_env(*args, **kwargs)
    env.append_transform(StorageProbe())
    return env
